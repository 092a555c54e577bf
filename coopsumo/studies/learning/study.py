"""`coopsumo learning` (`make learning`): what makes the shared DQN learn, one change at a time.

Two parts, both trained in free flow (3 lanes, T_up 1 s by default) and evaluated greedily on
evaluation seeds the models never trained on, beside baselines on the same evaluation seeds:

- the ablation: learner variants from the paper-literal setup to the default design, each adding
  one change to the one before (VARIANTS);
- the alpha response: the default design trained for every alpha of the grid.

A "cell" is one training seed of one variant and alpha (train, then one greedy evaluation on
evaluation seed EVAL_SEED_OFFSET + training seed) or one baseline evaluation. Cells run on the
scenario II runner (local processes or Ray), each finished cell is written atomically to
OUT/cells/<key>.json, and a rerun skips finished cells. Outputs in OUT (default
results/learning): cells/, train/<key>/, baselines/<key>/, runs.csv, summary.csv,
alpha_response.csv, fig_training_curves.png, fig_alpha_response.png, report.md.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from coopsumo.config import RoadConfig, SimConfig, to_dict
from coopsumo.dqn_config import DQNConfig
from coopsumo.errors import UsageError
from coopsumo.files import write_json
from coopsumo.provenance import versions
from coopsumo.run_markers import LEARNING_KIND
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.catalogue import (
    OWN_PROFILE,
    PlanFlag,
    add_plan_flags,
    own_profile,
    plan_from_flags,
    profile_arg,
)
from coopsumo.studies.engine.cells import Cell, CellKind, Run, Study
from coopsumo.studies.engine.records import CellRecords, failed_exit
from coopsumo.studies.engine.run_folders import (
    default_out,
    profile_study,
    recorded_profile,
    run_places,
    study_root,
)
from coopsumo.studies.engine.runner import add_backend_flags, check_backend
from coopsumo.studies.learning.plan import (
    CHAIN_LENGTH,
    PROFILES,
    REQUIRED_SUMMARY,
    VARIANT_NAMES,
    VARIANTS,
    Profile,
    cell_specs,
    learner_of,
    own_profiles,
    variant_list,
)
from coopsumo.studies.learning.report import write_outputs
from coopsumo.validation import alpha_list, default_model_out, model_out_dir, number_name, seed_count, workers

# -- one cell (in a worker process) ----------------------------------------------------------------
RECORDS = CellRecords(("key", "kind", "part", "variant", "alpha", "seed", "eval_seed", "policy"), ("train_summary",))
"""a cell's record: its coordinates and configuration, then what it measured"""
new_record, failed_record = RECORDS.new, RECORDS.failed


def work(spec: dict[str, Any]) -> Cell:
    """What the cell of `spec` does (cells.perform runs it): a training cell trains into ROOT/train/<key>/ (the model
    store's, resuming a matching checkpoint; cells share trainings), then drives the model greedily with the cell's
    drive settings (its policy string: cells.cell_train) on every evaluation seed into ROOT/evals/<key>/ (beside the
    training: the stored model folder holds the training only), the record's summary pooling them and eval_summaries
    keeping each; a baseline cell is one run into ROOT/baselines/<key>/."""
    from coopsumo.config import sim_config_from_dict
    from coopsumo.studies.engine.cells import cell_train

    if spec["kind"] != "train":
        return Cell(runs=(Run(sim_config_from_dict(spec["config"]["eval"]), f"baselines/{spec['key']}"),),
                    label=spec["key"])  # fmt: skip
    key = spec.get("train_key", spec["key"])
    evals = [sim_config_from_dict(raw) for raw in spec["config"]["evals"]]
    runs = tuple(Run(ev, f"evals/{key}/{eval_folder(spec, ev)}") for ev in evals)
    return Cell(cell_train(spec, f"train/{key}"), runs, spec["key"], pooled=True)


CELLS = CellKind(RECORDS, work)
run_cell = CELLS.run_cell


def eval_folder(spec: dict[str, Any], ev: SimConfig) -> str:
    """The run folder of a training cell's evaluation ev: eval_seed<seed>, then each drive setting it drives with
    (config.drive) as _margin<M>, _queue<V>, _noreturn<S>, and for an alpha-conditioned model _alpha<A>."""
    drive = spec["config"].get("drive", {})
    name = f"eval_seed{ev.seed}" + "".join(f"_{tag}{number_name(float(drive[f]))}" for tag, f in DRIVE_TAGS
                                           if drive.get(f))  # fmt: skip
    if spec["config"]["train"]["dqn"].get("alpha_conditioned"):  # driven at the cell's alpha (its evaluation's)
        name += f"_alpha{number_name(ev.reward.alpha)}"
    return name


DRIVE_TAGS = (("margin", "change_margin"), ("queue", "queue_below_mps"), ("noreturn", "no_return_s"))
"""the drive settings an evaluation's folder names, in its name's order: (its tag, its key in config.drive)"""


# -- the study -------------------------------------------------------------------------------------
def _places(root: Path, s: dict[str, Any]) -> Iterable[Path]:
    """A cell's run folders: a training cell's evaluations under ROOT/evals/<training>/, a baseline's ROOT/baselines/
    <key>/ (a user's files there refused before any cell runs: issue 82, probe 7, I1)."""
    train = s["kind"] == "train"
    return run_places(root / ("evals" if train else "baselines") / s.get("train_key", s["key"]), nested=train)


def _order(todo: list[dict[str, Any]]) -> None:
    """The slow paper trainings first, the single changes on top of the default last; a training shared by several
    cells (margin variants, a conditioned model's alphas) started by one cell first: the others wait for it (a lock),
    so every training comes before every cell that would wait."""
    extras = set(VARIANT_NAMES[CHAIN_LENGTH:])
    todo.sort(key=lambda s: (s["variant"] in extras and s["part"] == "ablation", s["kind"] != "train",
                             s["variant"] != "paper"))  # fmt: skip
    first: dict[str, str] = {}
    for s in todo:
        first.setdefault(s.get("train_key", s["key"]), s["key"])
    todo.sort(key=lambda s: first[s.get("train_key", s["key"])] != s["key"])


STUDY = Study("learning", CELLS, REQUIRED_SUMMARY, _places, _order, in_place=True)
"""the learning study as the engine runs it"""


def run_study(profile: Profile, root: Path, default: DQNConfig, backend_name: str = "local", workers: int = 2,
              address: str | None = None, progress: bool = True) -> dict[str, Any]:  # fmt: skip
    root = root.resolve()
    specs = cell_specs(profile, default)
    default_variant = next((n for n, _, c in VARIANTS if c == default), "default")
    learners = {v: to_dict(learner_of(v)) for v in dict.fromkeys((*profile.variants, *profile.alpha_variants))}
    meta: dict[str, Any] = {"profile": asdict(profile), "default_learner": to_dict(default), "cells": len(specs),
                            "default_variant": default_variant, "learners": learners,
                            "backend": backend_name, "workers": workers, "versions": versions()}  # fmt: skip

    def finish(records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
        meta["cell_wall_seconds_sum"] = round(sum(r.get("cell_wall_s") or 0.0 for r in records), 1)
        write_outputs(root, profile, records, meta)
        write_json(root / "study.json", meta)

    return STUDY.run(specs, root, meta, profile.name, finish, roads=[RoadConfig(lanes=profile.lanes)], workers=workers,
                     backend=backend_name, address=address, progress=progress)  # fmt: skip


def default_variant_name() -> str:
    """The variant whose learner is today's default (DQNConfig()): the one a profile without alpha_variants measures
    the alpha response of."""
    return next((n for n, _, c in VARIANTS if c == DQNConfig()), "default")


def _seeds(n: int, _profile: Profile) -> dict[str, Any]:
    if n <= 0:
        raise UsageError(f"--seeds must be positive, got {n}")
    return {"seeds": tuple(range(n))}


PLAN_FLAGS = (
    PlanFlag(("--variants",), lambda text, _: {"variants": variant_list("--variants", text)},
             f"comma-separated subset of {','.join(VARIANT_NAMES)}", lambda f: ",".join(f.variants)),
    PlanFlag(("--alphas",), lambda text, _: {"alphas": alpha_list("--alphas", text)},
             "comma-separated alpha grid of the alpha response", lambda f: ",".join(f"{a:g}" for a in f.alphas)),
    PlanFlag(("--alpha-variants",), lambda text, _: {"alpha_variants": variant_list("--alpha-variants", text)},
             "comma-separated variants whose alpha response is measured",
             lambda f: ",".join(f.alpha_variants) or f"the default learner, {default_variant_name()}"),
    PlanFlag(("--seeds", "--train-seeds"), _seeds, "models per variant: training seeds 0..N-1, each evaluated on its "
             "own held-out seed", lambda f: str(len(f.seeds)), seed_count, dest="seeds"),
)
"""the flags that set the profile's fields"""


def build_parser() -> Parser:
    p = Parser(prog="coopsumo learning",
               description="Ablation of the DQN learner and its alpha response (results/learning).")  # fmt: skip
    size = p.add_mutually_exclusive_group()  # one way to say the study's size
    size.add_argument("--profile", type=profile_arg(tuple(PROFILES)), default="full",
                      help=f"study size (full: paper scale; {', '.join(PROFILES)}), or a profile of your own in a "
                           f"file of [profiles.NAME] tables as in learning.toml, naming its variants, "
                           f"{OWN_PROFILE}")  # fmt: skip
    size.add_argument("--quick", action="store_true", help="the same as --profile quick")
    add_plan_flags(p, PLAN_FLAGS, PROFILES)
    p.add_argument("--workers", type=workers, default=2, help="parallel cells")
    add_backend_flags(p)
    p.add_argument("--out", type=model_out_dir, default=None,
                   help="results folder (default results/learning, another profile results/learning_<profile>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def chosen_profile(text: str) -> Profile:
    """--profile's profile: a packaged one by name, or one of a file of one's own (PATH.toml[:NAME]: [profiles.NAME]
    tables as in learning.toml, naming its variants, every profile checked as the packaged ones are)."""
    return PROFILES[text] if text in PROFILES else own_profile(text, own_profiles, PROFILES, "default")


def profile_from_args(args: Any) -> Profile:
    profile = plan_from_flags(PROFILES["quick"] if args.quick else chosen_profile(args.profile), args, PLAN_FLAGS)
    if args.workers <= 0:
        raise UsageError(f"--workers must be positive, got {args.workers}")
    return profile


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        profile = profile_from_args(args)
        check_backend(args.backend, args.address)
        if args.out is None:
            args.out = default_model_out(default_out("learning", profile.name, "full"))
        # path, lock, ownership (another profile's study refused; its own resumed) and marker of the results folder
        with study_root(args.out, LEARNING_KIND, profile_study(profile.name), recorded_profile("study.json", "profile",
                        "name", kind=LEARNING_KIND), f"pick another --out (the {profile.name} profile's default: "
                        f"{default_out('learning', profile.name, 'full')})", trains=True,
                        profile=PROFILES["quick"] if args.quick else chosen_profile(args.profile)):  # fmt: skip
            meta = run_study(profile, args.out, DQNConfig(), args.backend, args.workers, args.address,
                             progress=not args.quiet)  # fmt: skip
        print(f"learning: {meta['cells']} cells in {meta['wall_seconds']:.0f} s; report: {args.out / 'report.md'}")
        return failed_exit("learning", meta["failed_cells"], meta["cells"], args.out)

    return run_cli("learning", body)


if __name__ == "__main__":
    sys.exit(main())
