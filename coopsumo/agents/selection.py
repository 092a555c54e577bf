"""Model selection on held-out demand: the best training snapshot becomes model.pt.

Every DQNConfig.select_every_steps training steps the trainer saves the online network as
OUT/snapshots/step<N>/model.pt and validates it in a separate process (`python -m coopsumo.agents.selection DIR`;
libsumo holds one simulation per process, and the training's is open): one greedy free-flow run per demand of
DQNConfig.validation_t_ups, each DQNConfig.validation_steps long, on seeds validation_seed + i that no training
and no study evaluation uses; with DQNConfig.validation_accident_steps > 0, one more run per demand through an
accident (the next seeds). A snapshot drives as model.pt would, with its change margin; an alpha-conditioned one
at its training's alpha, or at each of DQNConfig.validation_alphas (every run once per alpha). The process writes
DIR/validation.json. The score is the run's own objective, the mean reward per vehicle and step (speed + flow -
alpha per lane change), averaged over the runs; ties go to the earlier snapshot. Validation never feeds back into
training: the same seed trains the same weights whether or not it runs, and whatever the machine's load.

The validation also records what the diagnosis of a training needs: the share of each action among the greedy
decisions, and the Q-value gap between the best lane change and the best of staying where a change is offered.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coopsumo.agents.snapshots import (  # also selection.*
    RESULT,
    SCREEN,
    SCREEN_STAGE,
    SNAPSHOTS,
    best,
    by_score,
    result,
    results,
    snapshot_dir,
)
from coopsumo.config import AccidentConfig, SimConfig, TrainConfig, sim_config_from_dict, to_dict
from coopsumo.field_rules import digits
from coopsumo.files import read_json, read_json_object, write_atomic

if TYPE_CHECKING:
    from coopsumo.agents.dqn_policy import DQNPolicy

REQUEST = "request.json"
LAST_MODEL = "model_last.pt"
"""the last weights of a training that selects its model (model.pt is the best snapshot)"""
NEAR_TIE = 0.05
"""a lane change and staying are near-tied when their Q-values differ by less than this share of |Q(stay)|"""


def selecting(cfg: TrainConfig) -> bool:
    """True when the training chooses model.pt among snapshots: selection is on and there are at least two
    (a training no longer than select_every_steps has one candidate, its last weights, and validates nothing)."""
    return 0 < cfg.dqn.select_every_steps < cfg.sim.steps


def validation_configs(cfg: TrainConfig, model: Path, screen: bool = False) -> list[SimConfig]:
    """The greedy runs that judge a snapshot of the training cfg: one in free flow per validation demand (seeds
    validation_seed + i), then, when validation_accident_steps > 0, one through an accident per demand (the next
    seeds): held at the default position from 1/12 of the run for 5/6 of it. With `screen`, only the runs of the
    screening demands (screen_t_ups), each the same run as in the full list."""
    dq = cfg.dqn
    base = replace(cfg.sim, steps=dq.validation_steps, policy=f"dqn:{model}")
    runs = [replace(base, demand=replace(base.demand, t_up_s=t), seed=dq.validation_seed + i)
            for i, t in enumerate(dq.validation_t_ups)]  # fmt: skip
    n = dq.validation_accident_steps
    if n:
        accident = AccidentConfig(enabled=True, start_step=n // 12, duration_steps=n * 5 // 6)
        runs += [replace(base, steps=n, accident=accident, demand=replace(base.demand, t_up_s=t),
                         seed=dq.validation_seed + len(dq.validation_t_ups) + i)
                 for i, t in enumerate(dq.validation_t_ups)]  # fmt: skip
    return [r for r in runs if r.demand.t_up_s in screen_t_ups(cfg)] if screen else runs


def screen_t_ups(cfg: TrainConfig) -> tuple[float, ...]:
    """The screening demands (T_up, s): the last DQNConfig.validation_screen of validation_t_ups, or none when that
    leaves no other run (every snapshot is then validated on every run)."""
    n, t_ups = cfg.dqn.validation_screen, cfg.dqn.validation_t_ups
    return t_ups[-n:] if 0 < n < len(t_ups) else ()


def screening(cfg: TrainConfig) -> bool:
    """True when snapshots are first judged on the screening runs alone (screen_t_ups)."""
    return bool(screen_t_ups(cfg))


def request(out: Path, cfg: TrainConfig, step: int, screen: bool = False) -> Path:
    """Write the validation request of the snapshot at `step` (its model.pt must exist), on the screening runs
    alone when `screen` (its result: screen.json, else validation.json); returns its folder."""
    folder = snapshot_dir(out, step)
    runs = [to_dict(c) for c in validation_configs(cfg, (folder / "model.pt").resolve(), screen)]
    alphas: list[float | None] = [None]
    if cfg.dqn.alpha_conditioned:  # a conditioned snapshot drives at its training's alpha, or at each one asked for
        alphas = list(cfg.dqn.validation_alphas or (cfg.sim.reward.alpha,))
    data: dict[str, Any] = {"step": step, "runs": runs * len(alphas), "stage": SCREEN_STAGE if screen else "all",
                            "drive_alphas": [a for a in alphas for _ in runs]}  # fmt: skip
    _write_json(folder / REQUEST, data)
    return folder


def answer_file(folder: Path) -> str:
    """The file the request of a snapshot folder is answered in: screen.json for a screening request, else
    validation.json."""
    data = read_json_object(folder / REQUEST)
    return SCREEN if data is not None and data.get("stage") == SCREEN_STAGE else RESULT


def answered(folder: Path) -> bool:
    """True when the request in `folder` has its result."""
    return result(folder, answer_file(folder)) is not None


def finalists(out: Path, cfg: TrainConfig) -> list[int]:
    """The steps of the snapshots that run every validation run after screening: the validation_finalists best
    screened (ties to the earlier), by step."""
    screened = [r for d in snapshot_folders(out) if (r := result(d, SCREEN)) is not None]
    return sorted(r["step"] for r in by_score(screened)[:cfg.dqn.validation_finalists])


def start() -> subprocess.Popen[bytes]:
    """The training's validation process (`python -m coopsumo.agents.selection --serve`): it validates the snapshot
    folders written to its stdin, one a line, in turn, and answers each with a line once its validation.json is
    written; one process a training, so that torch and libsumo are imported once, not once a snapshot (about 3 CPU s
    each). In a process group of its own: a Ctrl-C sent to the training's group is the training's to handle (it ends
    the validation, Validator.close), and cannot fail the validation first."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "coopsumo.agents.selection", "--serve"], env=env, bufsize=0,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            process_group=0)  # fmt: skip


def failure(folder: Path, proc: subprocess.Popen[bytes]) -> RuntimeError:
    """The error of a validation process that ended before it validated `folder`: the last line it wrote."""
    proc.wait()
    err = proc.stderr.read().decode(errors="replace").strip().splitlines() if proc.stderr else []
    return RuntimeError(f"validation of {folder} failed: {err[-1] if err else f'exit {proc.returncode}'}")


def pending(out: Path) -> list[Path]:
    """Snapshot folders with a request and a model but no result for it (a resume validates them again)."""
    return [d for d in snapshot_folders(out)
            if (d / REQUEST).exists() and (d / "model.pt").exists() and not answered(d)]


def install_best(out: Path) -> dict[str, Any] | None:
    """Copy the best validated snapshot to out/model.pt (atomically: a kill leaves the old file or the new one)."""
    chosen = best(results(out))
    if chosen is None:
        return None
    write_atomic(out / "model.pt", lambda tmp: shutil.copyfile(snapshot_dir(out, chosen["step"]) / "model.pt", tmp))
    return chosen


def snapshot_folders(out: Path) -> list[Path]:
    """A training's snapshot folders, by step."""
    found = [d for d in (out / SNAPSHOTS).glob("step*") if digits(d.name[4:])]
    return sorted(found, key=lambda d: int(d.name[4:]))


def last_result(folder: Path) -> tuple[dict[str, Any] | None, str]:
    """A snapshot's fullest validation and its stage: on every run ("all"), else on the screening runs, else None."""
    full = result(folder)
    return (full, "all") if full is not None else (result(folder, SCREEN), SCREEN_STAGE)


def last_score(out: Path) -> float:
    """The validation score of a training's last snapshot, on every run, or on the screening runs when it was not
    a finalist (validation.csv's stage column says which)."""
    return float(last_result(snapshot_folders(out)[-1])[0]["score"])  # type: ignore[index]


SCREEN_COLUMNS = ("score", "mean_speed_mps", "lane_changes_per_vehicle", "share_none")
"""a two-stage selection's screening measures in validation.csv (screen_<name>), for every snapshot"""


def write_table(out: Path) -> None:
    """OUT/validation.csv: one row per validated snapshot (score, per-demand measures, diagnosis), `best` marked;
    after a selection in two stages, each row's stage and its screening measures (SCREEN_COLUMNS)."""
    import pandas as pd

    chosen = best(results(out))
    rows = [(r, stage) for r, stage in map(last_result, snapshot_folders(out)) if r is not None]
    if not rows:
        return
    staged = any(stage == SCREEN_STAGE for _, stage in rows)  # two stages: say which runs each score is over
    flat = []
    for r, stage in rows:
        row = {"step": r["step"], "score": r["score"], "best": chosen is not None and r["step"] == chosen["step"]}
        if staged:  # every snapshot's screening measures too: the same runs for all, comparable along the training
            screened = result(snapshot_dir(out, r["step"]), SCREEN) or {}
            row["stage"] = stage
            row.update({f"screen_{k}": screened.get(k) for k in SCREEN_COLUMNS})
        row.update({k: v for k, v in r.items() if k not in ("step", "score", "runs")})
        several = len({run.get("alpha") for run in r["runs"]}) > 1  # validated at several alphas
        for run in r["runs"]:
            tag = f"{'accident_' if run.get('accident') else ''}t{run['t_up_s']:g}"
            if several:
                tag += f"_alpha{run['alpha']:g}"
            for key in ("mean_speed_mps", "lane_changes_per_vehicle", "mean_reward"):
                row[f"{key}_{tag}"] = run[key]
        flat.append(row)
    pd.DataFrame(flat).to_csv(out / "validation.csv", index=False, float_format="%.6g")


def _write_json(path: Path, data: dict[str, Any]) -> None:
    text = json.dumps(data, indent=1)
    write_atomic(path, lambda tmp: tmp.write_text(text))


SELECTION_FIELDS = ("validation_seed", "validation_t_ups", "validation_steps", "validation_accident_steps",
                    "validation_screen", "validation_finalists",
                    "validation_alphas", "change_margin", "queue_below_mps", "no_return_s")
"""learner settings that training never reads, only the judging of snapshots (the change margin, the queue rule and
no change back also the driving): two trainings that differ in nothing else train the same weights"""


def trained_part(learner: dict[str, Any]) -> dict[str, Any]:
    """A learner (DQNConfig dict) without SELECTION_FIELDS: two learners with equal parts train the same weights."""
    return {k: v for k, v in learner.items() if k not in SELECTION_FIELDS}


def reselect(src: Path, out: Path, cfg: TrainConfig) -> dict[str, Any]:
    """Make `out` a finished training folder of cfg from `src`, a finished training that differs from cfg only in
    SELECTION_FIELDS: the same snapshots, last weights and training log (rewritten under cfg's configuration),
    validated again with cfg's validation, the best installed as model.pt. No training step runs (validation never
    feeds back into training, so these are the weights cfg would train). Returns out's train summary."""
    from coopsumo.agents.model_file import load_model, save_model
    from coopsumo.files import write_json
    from coopsumo.provenance import versions
    from coopsumo.run_dirs import mark_run_dir

    meta = {"config": to_dict(cfg), "versions": versions()}
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    mark_run_dir(out, "train", finished=False)
    write_json(out / "config.json", meta)
    for name in ("train_log.csv", "sumo", "tensorboard"):
        if (src / name).is_dir():
            shutil.copytree(src / name, out / name)
        elif (src / name).is_file():
            shutil.copyfile(src / name, out / name)
    net, _ = load_model(src / LAST_MODEL)
    save_model(out / LAST_MODEL, net, meta)
    steps = [int(d.name[4:]) for d in snapshot_folders(src)]
    validator = Validator(out, cfg, max(steps, default=0))
    try:
        for step in steps:
            net, _ = load_model(snapshot_dir(src, step) / "model.pt")
            snapshot_dir(out, step).mkdir(parents=True)
            save_model(snapshot_dir(out, step) / "model.pt", net, meta)
            validator.queue.append(request(out, cfg, step, screening(cfg)))
        validator.finish()
    finally:
        validator.close()
    chosen = install_best(out)
    if chosen is None:
        raise RuntimeError(f"{src} has no snapshots to choose from")
    write_table(out)
    summary = read_json(src / "train_summary.json")
    summary.update(selected_step=chosen["step"], selected_score=chosen["score"], last_score=last_score(out),
                   reselected_from=src.name)  # fmt: skip
    write_json(out / "train_summary.json", summary)
    mark_run_dir(out, "train")
    return summary


# -- the validation process -------------------------------------------------------------------------
def diagnosis(rows: list[np.ndarray]) -> dict[str, float]:
    """Action shares and Q-gap measures of greedy decisions; rows: [Q (4), offered (4), action] per decision."""
    from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP

    if not rows:
        return {}
    d = np.concatenate(rows)
    q, mask, action = d[:, :4], d[:, 4:8].astype(bool), d[:, 8].astype(int)
    out = {f"share_{name}": float((action == a).mean())
           for name, a in (("left", LEFT), ("right", RIGHT), ("speedup", SPEEDUP), ("none", NONE))}  # fmt: skip
    can_change = mask[:, LEFT] | mask[:, RIGHT]
    out["change_offered_share"] = float(can_change.mean())
    if can_change.any():
        q_change = np.where(mask[:, [LEFT, RIGHT]], q[:, [LEFT, RIGHT]], -np.inf).max(axis=1)[can_change]
        q_stay = np.where(mask[:, [SPEEDUP, NONE]], q[:, [SPEEDUP, NONE]], -np.inf).max(axis=1)[can_change]
        gap = q_change - q_stay
        out["q_gap_median"] = float(np.median(gap))
        out["near_tie_share"] = float((np.abs(gap) < NEAR_TIE * np.abs(q_stay)).mean())
        out["change_chosen_share"] = float(np.isin(action[can_change], [LEFT, RIGHT]).mean())
    return out


def snapshot_policy(path: str) -> DQNPolicy:
    """A snapshot as validation drives it: as saved, but with the queue rule (DQNConfig.queue_below_mps) off, as
    training drives."""
    from coopsumo.agents.dqn_policy import DQNPolicy

    policy = DQNPolicy.from_file(path)
    policy.queue_below_mps = 0.0
    return policy


def validate_run(cfg: SimConfig, drive_alpha: float | None, folder: Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """One greedy run of the snapshot (snapshot_policy): its measures and the recorded decisions (diagnosis)."""
    from coopsumo.agents.decisions import ActionHold
    from coopsumo.sim.world import World

    policy = snapshot_policy(cfg.policy[4:])
    if drive_alpha is not None:
        policy.drive_at(drive_alpha, cfg.road.lanes)
    policy.q_log = []
    hold = ActionHold(policy.decision_interval)
    reward = 0.0
    samples = 0
    with World(cfg, folder, observe_grids=True) as world:
        for _ in range(cfg.steps):
            decide = hold.is_decision_step(world.step_count)
            obs = world.observe(grids=decide)
            out = world.apply(hold.actions(obs.nums, policy.act(obs) if decide else None))
            reward += float(out.reward.total.sum())
            samples += len(out.nums)
        summary = world.summary()
    run = {"t_up_s": cfg.demand.t_up_s, "accident": cfg.accident.enabled, "seed": cfg.seed, "alpha": drive_alpha,
           "mean_reward": reward / max(samples, 1),
           **{k: summary[k] for k in ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")}}
    return run, policy.q_log


Kept = dict[str, dict[str, tuple[dict[str, Any], list[np.ndarray]]]]
"""a validation process's screening runs, by snapshot folder and run (its configuration and alpha as JSON): their
records and decisions, so that a finalist's full validation takes them instead of running them again"""


def validate(folder: Path, kept: Kept | None = None) -> dict[str, Any]:
    """Run the request in folder, write its result (validation.json, or screen.json for a screening request),
    return it. With `kept` (the validation process's), a screening request's runs are kept there, and a full one
    takes the kept runs of its folder (the same configuration and seed: the same result) instead of running them."""
    import torch

    torch.set_num_threads(1)
    req = read_json(folder / REQUEST)
    screen = req.get("stage") == SCREEN_STAGE
    reuse = kept.pop(str(folder), {}) if kept is not None and not screen else {}
    made: dict[str, tuple[dict[str, Any], list[np.ndarray]]] = {}
    runs, rows = [], []
    alphas = req.get("drive_alphas") or [req.get("drive_alpha")] * len(req["runs"])  # one alpha: an older request
    for i, (raw, alpha) in enumerate(zip(req["runs"], alphas, strict=True)):
        key = json.dumps([raw, alpha], sort_keys=True)
        if key not in reuse:
            with tempfile.TemporaryDirectory(dir=folder, prefix=f".run{i}.") as tmp:
                made[key] = validate_run(sim_config_from_dict(raw), alpha, Path(tmp))
        run, log = reuse.get(key) or made[key]
        runs.append(run)
        rows += log
    score = float(np.mean([r["mean_reward"] for r in runs]))
    data = {"step": int(req["step"]), "score": score,
            "mean_speed_mps": float(np.mean([r["mean_speed_mps"] for r in runs])),
            "lane_changes_per_vehicle": float(np.mean([r["lane_changes_per_vehicle"] for r in runs])),
            **diagnosis(rows), "runs": runs}  # fmt: skip
    _write_json(folder / (SCREEN if screen else RESULT), data)
    if screen and kept is not None:
        kept[str(folder)] = made
    return data


def serve() -> int:
    """Validate the snapshot folders read from stdin, one a line, answering each on stdout when its result is
    written; ends at the end of its input. A finalist's screening runs are taken from its screening (validate)."""
    kept: Kept = {}
    for line in sys.stdin:
        validate(Path(line.rstrip("\n")), kept)
        sys.stdout.write("done\n")
        sys.stdout.flush()
    return 0


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args == ["--serve"]:
        return serve()
    if len(args) != 1 or not (Path(args[0]) / REQUEST).exists():
        print("usage: python -m coopsumo.agents.selection SNAPSHOT_FOLDER (holding request.json) | --serve",
              file=sys.stderr)  # fmt: skip
        return 2
    validate(Path(args[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())


class Validator:
    """The trainer's side of model selection: snapshots every select_every_steps (and at the last step),
    validated one at a time in one background process (start) while training goes on."""

    def __init__(self, out: Path, cfg: TrainConfig, resumed_step: int = 0):
        self.out = out
        self.cfg = cfg
        self.every = cfg.dqn.select_every_steps
        self.queue: list[Path] = []
        self.running: Path | None = None
        """the snapshot folder the process is validating"""
        self.proc: subprocess.Popen[bytes] | None = None
        (out / SNAPSHOTS).mkdir(exist_ok=True)
        for d in (out / SNAPSHOTS).glob("step*"):  # a resume re-trains the steps after its checkpoint
            if not digits(d.name[4:]) or int(d.name[4:]) > resumed_step:
                shutil.rmtree(d, ignore_errors=True)
        self.queue = pending(out)

    def after_step(self, step: int, weights: Callable[[], Any]) -> None:
        """Called after every training step; weights() gives the network that drives (Learner.online; called only
        when a snapshot is due: with an update worker, it waits for the updates sent)."""
        if step % self.every == 0 or step == self.cfg.sim.steps:
            net = weights()
            from coopsumo.agents.model_file import save_model
            from coopsumo.provenance import versions

            folder = snapshot_dir(self.out, step)
            folder.mkdir(parents=True, exist_ok=True)
            save_model(folder / "model.pt", net, {"config": to_dict(self.cfg), "versions": versions()})
            self.queue.append(request(self.out, self.cfg, step, screening(self.cfg)))
            self.poll()
        elif step % 1000 == 0:
            self.poll()

    def _collect(self, wait: bool) -> bool:
        """True once the running validation has answered (waiting for it if `wait`); RuntimeError if its process
        ended first or answered without a result."""
        import select

        assert self.running is not None and self.proc is not None and self.proc.stdout is not None
        if not wait and not select.select([self.proc.stdout], [], [], 0)[0]:
            return False
        if self.proc.stdout.readline() != b"done\n" or not answered(self.running):
            raise failure(self.running, self.proc)
        self.running = None
        return True

    def poll(self) -> None:
        """Collect a finished validation and start the next one."""
        if self.running is not None and not self._collect(wait=False):
            return
        if self.queue:
            if self.proc is None:
                self.proc = start()
            self.running = self.queue.pop(0)
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write(f"{self.running.resolve()}\n".encode())
            except BrokenPipeError:
                raise failure(self.running, self.proc) from None

    def finish(self) -> None:
        """Wait until every snapshot is validated (after screening, the finalists on every run), then end the
        validation process."""
        self._drain()
        if screening(self.cfg):
            self.queue = [request(self.out, self.cfg, step) for step in finalists(self.out, self.cfg)
                          if result(snapshot_dir(self.out, step)) is None]  # fmt: skip
            self._drain()
        if self.proc is not None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            self.proc.wait()
            self.proc = None

    def _drain(self) -> None:
        while self.running is not None or self.queue:
            if self.running is not None:
                self._collect(wait=True)
            self.poll()

    def close(self) -> None:
        """Stop the validation process (interrupted training: a resume validates its snapshot again)."""
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.terminate()
                self.proc.wait()
            self.proc = None
        self.running = None
