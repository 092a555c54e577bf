"""The ablation command on its tiny profile: every cell runs, the tables and report are written, reruns reuse."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest
from conftest import InlineBackend, assert_refused_in_one_line, main_here

from coopsumo.agents.selection import trained_part
from coopsumo.dqn_config import PAPER_DQN, DQNConfig
from coopsumo.studies.learning.plan import (
    CHAIN_LENGTH,
    PROFILES,
    VARIANTS,
    as_trained,
    cell_specs,
    learner_of,
)
from coopsumo.studies.learning.report import is_monotone_decreasing

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent


def test_variants_add_one_change_at_a_time_from_paper_to_default() -> None:
    assert VARIANTS[0][0] == "paper" and learner_of("paper") == PAPER_DQN
    fields = DQNConfig.__dataclass_fields__
    chain = VARIANTS[:CHAIN_LENGTH]
    branch_base = next(v for v in chain if v[0] == "noreturn")  # the branches were made off the chain's end then
    pairs = list(zip(chain, chain[1:], strict=False)) + [(branch_base, extra) for extra in VARIANTS[CHAIN_LENGTH:]]
    for (_, _, before), (name, _, after) in pairs:
        changed = [f for f in fields if f != "preset" and getattr(before, f) != getattr(after, f)]
        assert 1 <= len(changed) <= 3, (name, changed)  # one idea (e.g. replay size + its update rate)
    # the default design is judged by the learner protocol, one change at a time from the learning study's `select`
    from coopsumo.studies.protocol.plan import variants

    protocol = variants()
    assert protocol["nr10"].learner == learner_of("noreturn") and chain[-1][0] == "stacked"
    assert protocol["stks"].learner == DQNConfig() == learner_of("stacked")
    assert protocol["f05q_ts2k"].learner == learner_of("target")
    assert learner_of("select") == protocol["select"].learner


def test_every_model_meets_every_evaluation_seed_and_none_is_a_training_seed() -> None:
    profile = PROFILES["full"]
    specs = cell_specs(profile, DQNConfig())
    train_seeds = {s["seed"] for s in specs}
    seeds = [1000 + s for s in profile.seeds]
    models = [s for s in specs if s["kind"] == "train"]
    assert models and all([e["seed"] for e in s["config"]["evals"]] == seeds for s in models)
    assert sorted(s["eval_seed"] for s in specs if s["kind"] == "baseline") == sorted(seeds * 4)  # 4 baselines
    assert not set(seeds) & train_seeds


def test_monotone_check() -> None:
    assert is_monotone_decreasing([3.0, 2.0, 2.1, 1.0], [0.2, 0.2, 0.2, 0.1])
    assert not is_monotone_decreasing([3.0, 2.0, 2.9, 1.0], [0.2, 0.2, 0.2, 0.1])


def test_tiny_study_runs_and_a_rerun_reuses_every_cell(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The tiny study as a process, as a user runs it; its reruns, which judge what it left, by learning's main in
    this process (its workers' output captured too)."""
    from coopsumo.studies.learning import study as learning

    out = tmp_path / "learning"
    cmd = [sys.executable, "-m", "coopsumo", "learning", "--profile", "tiny", "--workers", "2", "--out", str(out),
           "--quiet"]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    runs = pd.read_csv(out / "runs.csv")
    profile = PROFILES["tiny"]
    n_train = len(profile.seeds) * len(profile.variants)
    assert (runs["status"] == "ok").all()
    assert len(runs[runs["kind"] == "baseline"]) == 4 * len(profile.seeds)
    assert len(runs[runs["kind"] == "train"]) >= n_train
    assert (runs["collisions"] == 0).all() and (runs["teleports"] == 0).all()
    report = (out / "report.md").read_text()
    assert "| paper |" in report and "| mobil:p=0.5 |" in report and "Alpha response" in report
    assert "mean speed minus `keep`" in report
    assert "## Seed robustness at alpha = 0" in report and "| `v2x` |" in report  # the v2x state end to end
    assert "| `paper` -> `interval` |" in report and "| `interval` -> `v2x` |" in report  # the chain, step by step
    # the margin2 variant drove the target models (the default's): no training of its own, evaluations beside
    assert not list((out / "train").glob("margin2_*"))
    assert list((out / "evals").glob("target_alpha0_seed0/eval_*_margin2_queue5_noreturn10"))  # beside the stored model
    for fig in ("fig_training_curves.png", "fig_alpha_response.png", "fig_training_seeds.png"):
        assert (out / fig).stat().st_size > 1000
    study = json.loads((out / "study.json").read_text())
    assert study["cells_run"] == study["cells"]
    # the experiment beside the study reads its models (as docs/studies.md runs it)
    acc = subprocess.run([sys.executable, "-m", "coopsumo", "accident-seeds", str(out), "--variants", "margin2",
                          "--alphas", "0", "--seeds", "1", "--steps", "900", "--t-up", "3",
                          "--out", str(tmp_path / "acc")],
                         cwd=ROOT, capture_output=True, text=True)  # fmt: skip
    assert acc.returncode == 0, acc.stderr[-2000:]
    acc_runs = pd.read_csv(tmp_path / "acc" / "runs.csv")
    assert set(acc_runs["variant"]) == {"keep", "greedy", "mobil:p=0", "margin2"}
    assert (acc_runs["collisions"] == 0).all() and (acc_runs["teleports"] == 0).all()
    assert "`margin2` | 0 | 1 |" in (tmp_path / "acc" / "report.md").read_text()
    code, _, err = main_here(learning.main, cmd[4:], capfd)
    assert code == 0, err[-2000:]
    assert json.loads((out / "study.json").read_text())["cells_run"] == 0
    assert pd.read_csv(out / "runs.csv").equals(runs)
    # issue 82, fifth probe, G6: a training whose log holds a speed of 999 m/s was drawn; it is trained again, with
    # one line naming the log and the field, and only the cells of that training run again
    log = sorted((out / "train").iterdir())[0] / "train_log.csv"
    lines = log.read_text().splitlines(keepends=True)
    cells = lines[1].split(",")
    cells[lines[0].strip().split(",").index("mean_speed_mps")] = "999"
    log.write_text("".join([lines[0], ",".join(cells), *lines[2:]]))
    code, _, err = main_here(learning.main, cmd[4:], capfd)
    assert code == 0 and "Traceback" not in err, err[-2000:]
    assert f"learning: {log} has mean_speed_mps = '999' in its row of step " in err, err[-2000:]
    assert "; training it again" in err and ",999," not in log.read_text()
    assert 0 < json.loads((out / "study.json").read_text())["cells_run"] < study["cells"]


@pytest.mark.parametrize(
    "args, fragment",
    [(["--variants", "paper,warp"], "warp"), (["--alphas", "0,-1"], "alphas"), (["--seeds", "0"], "seeds"),
     (["--workers", "0"], "workers"), (["--alphas", "a,b"], "alphas"), (["--alpha-variants", "v2x,x"], "x")],
)  # fmt: skip
def test_bad_input_one_line_exit_2(tmp_path: Path, args: list[str], fragment: str,
                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """learning's main in this process (the one-line refusal of a command run as a process:
    tests/test_bad_inputs.py)."""
    from coopsumo.studies.learning import study

    out = tmp_path / "out"
    code, _, err = main_here(study.main, ["--profile", "tiny", "--out", str(out), *args], capsys)
    assert_refused_in_one_line(code, err, out, fragment)


def test_default_alpha_zero_cells_are_shared_between_the_parts() -> None:
    profile = replace(PROFILES["tiny"], variants=("paper", "dueling"))
    keys = [s["key"] for s in cell_specs(profile, DQNConfig())]
    assert len(keys) == len(set(keys))
    assert sum(k.startswith("dueling_alpha0_") for k in keys) == len(profile.seeds)


def failing_cell(spec: dict[str, object], root: str) -> dict[str, object]:
    """Runs no SUMO: every cell is recorded failed at once."""
    from coopsumo.studies.learning.study import failed_record

    return failed_record(spec, "RuntimeError: SUMO said no")


def test_an_all_failed_study_exits_1_and_gives_no_verdict(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Its cells are recorded failed at once (failing_cell), so no cell reads a model: the stacked learner's trainings,
    which the engine runs as groups before the cells, are skipped too (as tests/test_scenario2.py's faked_train skips
    them; the groups train for real in test_tiny_study_runs_and_a_rerun_reuses_every_cell). They trained a group of
    real models in SUMO here that no assertion read (10 to 20 s)."""
    from coopsumo.studies.engine import cells, groups
    from coopsumo.studies.learning import study as ablation

    monkeypatch.setattr(cells, "make_backend", lambda name, workers, address, cell_fn: InlineBackend(failing_cell))
    monkeypatch.setattr(groups, "train_groups", lambda *a, **k: 0)
    monkeypatch.setattr("coopsumo.sim.network.build_net", lambda road: None)
    from coopsumo.run_dirs import mark_run_dir
    from coopsumo.run_markers import LEARNING_KIND
    from coopsumo.studies.engine.run_folders import profile_study

    mark_run_dir(tmp_path, LEARNING_KIND, finished=False, study=profile_study("tiny"))  # the study's, interrupted
    (tmp_path / "cells").mkdir()
    (tmp_path / "cells" / "keep_seed0.json").write_text('{"status": "ok", "summary": {}}')  # never trusted
    code = ablation.main(["--profile", "tiny", "--alphas", "8,8.000001", "--out", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    n = len(cell_specs(replace(PROFILES["tiny"], alphas=(8.0, 8.000001)), DQNConfig()))
    assert code == 1 and "Traceback" not in "\n".join(err)
    assert any("cell keep_seed0: record" in e and "summary is {}" in e for e in err)
    assert err[-1].startswith(f"learning: error: {n} of {n} cells failed (") and "_alpha8.000001_seed0" in err[-1]
    report = (tmp_path / "report.md").read_text()
    assert "**No verdict**" in report and "Failed cells: " in report and "_alpha8_seed0" in report
    assert "monotonically" not in report and "mean speed minus" not in report


def test_robustness_table_compares_each_model_with_the_baselines_over_the_same_seeds() -> None:
    from coopsumo.studies.followups import robustness

    def row(variant: str, kind: str, seed: int, speed: float, lc: float) -> dict[str, object]:
        return {"key": f"{variant}_{seed}", "kind": kind, "part": "ablation" if kind == "train" else "baseline",
                "variant": variant, "alpha": 0.0 if kind == "train" else None, "seed": seed,
                "eval_seed": None if kind == "train" else 1000 + seed, "status": "ok", "mean_speed_mps": speed,
                "lane_changes_per_vehicle": lc}  # fmt: skip
    runs = pd.DataFrame([
        row("dqn", "train", 0, 17.0, 1.0), row("dqn", "train", 1, 15.0, 4.0), row("dqn", "train", 2, 16.6, 0.5),
        row("keep", "baseline", 0, 16.5, 0.0), row("keep", "baseline", 1, 16.0, 0.0),
        row("keep", "baseline", 2, 16.7, 0.0),
    ])  # fmt: skip
    table = robustness.robustness_table(runs, ["dqn"], ["keep"])
    r = table.iloc[0]
    assert r["seeds"] == 3 and r["worst_seed"] == 1 and r["worst_speed"] == 15.0 and r["worst_lane_changes"] == 4.0
    keep = (16.5 + 16.0 + 16.7) / 3  # every model met all three evaluation seeds: keep's mean over them
    assert r["keep_below"] == 1  # seed 1 (15.0): a mean above keep does not hide it
    assert r["keep_gap_min"] == pytest.approx(15.0 - keep) and r["keep_gap_mean"] == pytest.approx(
        (17.0 + 15.0 + 16.6) / 3 - keep)
    # another learner's models are paired by training seed
    other = runs.assign(variant=runs["variant"].replace({"dqn": "other"}), mean_speed_mps=runs["mean_speed_mps"] - 1)
    gaps = robustness.paired_gaps(pd.concat([runs, other[other["kind"] == "train"]]), "dqn", "other")
    assert list(gaps) == pytest.approx([1.0, 1.0, 1.0])
    text = "\n".join(robustness.markdown(table, ["keep"]))
    assert "15.00 (4.00), seed 1" in text and "(1)" in text
    matrix = "\n".join(robustness.seed_matrix_markdown(robustness.per_seed_table(runs, ["dqn"], ["keep"])))
    assert "| `dqn` | 17.00 (1.00) | 15.00 (4.00) | 16.60 (0.50) |" in matrix


def test_each_chain_step_is_paired_by_training_seed() -> None:
    """A change that helps every model has an interval above 0; one whose models split is undecided; the worst
    model of a step is named (no SUMO: a hand-made table)."""
    from coopsumo.studies.followups import robustness

    def row(variant: str, seed: int, speed: float) -> dict[str, object]:
        return {"key": f"{variant}_{seed}", "kind": "train", "part": "ablation", "variant": variant, "alpha": 0.0,
                "seed": seed, "eval_seed": None, "status": "ok", "mean_speed_mps": speed}
    speeds = {"a": (15.0, 16.0, 14.0), "b": (16.0, 17.2, 15.1), "c": (17.0, 16.0, 15.2)}
    runs = pd.DataFrame([row(v, seed, x) for v, xs in speeds.items() for seed, x in enumerate(xs)])
    steps = robustness.chain_steps(runs, ["a", "b", "c"]).set_index("variant")
    assert steps.loc["b", "better"] == 3 and steps.loc["b", "diff_mean"] == pytest.approx(1.1)
    assert steps.loc["b", "diff_low"] > 0  # +1.0, +1.2, +1.1: decidedly faster
    assert steps.loc["c", "better"] == 2 and steps.loc["c", "diff_min"] == pytest.approx(-1.2)
    assert steps.loc["c", "diff_low"] < 0 < steps.loc["c", "diff_high"] and steps.loc["c", "worst"] == 15.2
    text = "\n".join(robustness.chain_markdown(robustness.chain_steps(runs, ["a", "b", "c"])))
    assert "| `a` -> `b` | +1.10 [" in text and "| 3 of 3 |" in text and "decidedly helped or hurt on these " \
        "models): `b`." in text


def test_a_longer_variant_trains_its_own_model_for_its_steps() -> None:
    """STEPS_FACTOR: conditioned8v_2x trains twice the profile's steps, a training of its own (not conditioned8v's,
    whose learner it shares), and the report's profile line names it."""
    from coopsumo.studies.learning import plan as ablation_plan
    from coopsumo.studies.learning.report import _longer

    profile = PROFILES["conditioned"]
    specs = [s for s in cell_specs(profile, DQNConfig()) if s["kind"] == "train"]
    longer = [s for s in specs if s["variant"] == "conditioned8v_2x"]
    plain = [s for s in specs if s["variant"] == "conditioned8v"]
    assert longer and plain and learner_of("conditioned8v_2x") == learner_of("conditioned8v")
    assert {s["config"]["train"]["sim"]["steps"] for s in longer} == {2 * profile.train_steps}
    assert {s["config"]["train"]["sim"]["steps"] for s in plain} == {profile.train_steps}
    assert not {s["train_key"] for s in longer} & {s["train_key"] for s in plain}
    assert _longer(profile) == " (`conditioned8v_2x` 180,000)" and _longer(PROFILES["quick"]) == ""
    # a per-alpha variant trained longer is nobody's twin: it keeps a training of its own
    factors = {**ablation_plan.STEPS_FACTOR, "margin2": 2}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ablation_plan, "STEPS_FACTOR", factors)
        short = replace(profile, train_steps=300, variants=("target", "margin2"), alpha_variants=())
        keys = {s["variant"]: s["train_key"] for s in cell_specs(short, DQNConfig())
                if s["kind"] == "train" and s["seed"] == 0 and s["alpha"] == 0}
    # the default's alpha response (stacked: its updates differ from target's) trains a model of its own
    assert keys == {"target": "target_alpha0_seed0", "margin2": "margin2_alpha0_seed0",
                    "stacked": "stacked_alpha0_seed0"}


def test_a_margin_variant_drives_its_twins_training() -> None:
    profile = replace(PROFILES["full"], alpha_variants=("restart", "margin", "followers", "queue", "target",
                                                        "margin2"))  # fmt: skip
    specs = {s["key"]: s for s in cell_specs(profile, DQNConfig())}
    twin, queue = specs["followers_alpha0_seed2"], specs["queue_alpha0_seed2"]
    target, driven = specs["target_alpha0_seed2"], specs["margin2_alpha0_seed2"]
    assert queue["train_key"] == twin["key"] == twin["train_key"]
    assert queue["config"]["train"] == twin["config"]["train"]  # one training: validation leaves the queue rule off
    assert target["train_key"] == target["key"] != queue["train_key"]  # a training of its own
    # model selection drives the snapshots with the change margin, as `coopsumo train` does: margin2's model.pt is
    # chosen with a margin of 2 (from the same weights: the store validates target's snapshots again)
    assert driven["train_key"] == driven["key"]
    assert driven["config"]["train"]["dqn"]["change_margin"] == 2.0
    assert target["config"]["train"]["dqn"]["change_margin"] == 1.0 == DQNConfig().change_margin
    assert trained_part(driven["config"]["train"]["dqn"]) == trained_part(target["config"]["train"]["dqn"])
    assert twin["config"]["drive"] == {"change_margin": 1.0}
    assert queue["config"]["drive"] == target["config"]["drive"] == {"change_margin": 1.0, "queue_below_mps": 5.0}
    assert driven["config"]["drive"] == {"change_margin": 2.0, "queue_below_mps": 5.0, "no_return_s": 10.0}
    assert specs["margin_alpha8_seed1"]["train_key"] == "restart_alpha8_seed1"  # no model selection: the margin unread
    tiny = {s["key"]: s for s in cell_specs(replace(profile, train_steps=300), DQNConfig())}
    assert tiny["margin2_alpha0_seed2"]["train_key"] == "target_alpha0_seed2"  # 300 steps select nothing
    assert tiny["margin2_alpha0_seed2"]["config"]["train"] == tiny["target_alpha0_seed2"]["config"]["train"]
    nr = replace(DQNConfig(), no_return_s=10.0)  # no change back: kept where validation drives with it, like the margin
    assert as_trained(nr, 90_000).no_return_s == 10.0 and as_trained(nr, 300).no_return_s == 0.0
    assert as_trained(replace(nr, queue_below_mps=5.0), 90_000).queue_below_mps == 0.0  # validation leaves it off
