"""`coopsumo scenario1` (`make scenario1`): the accident-bottleneck study of section IV.A, across demands.

1. takes one model per learner preset, alpha and training seed (default 5 seeds) from the model store
   (studies/engine/model_store.py), training those it does not hold;
2. runs every model and every baseline (keep, greedy, MOBIL at every politeness, SUMO's own models, and any
   policy given by --baseline: a class of one's own, a Stable-Baselines3 model, ...) through the accident at every
   demand T_up, on the same evaluation seeds;
3. writes results/scenario1/: run folders runs/t<T_up>/<policy>[_m<training seed>]_seed<k>/ (with SUMO's
   detectors.xml, fcd.xml and tripinfo.xml), runs.csv, summary.csv, the figures and report.md; with a display,
   gui_jam.png: sumo-gui's view of the jam at the bottleneck, replayed through TraCI.

The plan (sizes, configurations, names; the profiles: experiments_data/scenario1.toml) is scenario1_plan, the
measures scenario1_measures, the report scenario1_report; this module runs the plan's cells on the shared study
engine (engine/cells.Study: what is left to run, the trainings first, as groups) and is the command.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import ControlConfig, RoadConfig, as_data, to_dict
from coopsumo.errors import UsageError
from coopsumo.files import write_atomic, write_json
from coopsumo.provenance import versions
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.catalogue import (
    OWN_PROFILE,
    PlanFlag,
    add_plan_flags,
    at_least,
    by_profile,
    numbers,
    own_profile,
    plan_from_flags,
    profile_arg,
)
from coopsumo.studies.engine.cells import Study
from coopsumo.studies.engine.model_store import FIRST_TRAIN_SEED, store_for, stored_model
from coopsumo.studies.engine.records import failed_exit
from coopsumo.studies.engine.run_folders import profile_study, recorded_profile, study_root
from coopsumo.studies.engine.runner import add_backend_flags, check_backend
from coopsumo.studies.scenario1 import regime_map
from coopsumo.studies.scenario1.accident_runs import CELLS, REQUIRED, folder_reusable, places
from coopsumo.studies.scenario1.measures import aggregate, run_metrics
from coopsumo.studies.scenario1.plan import (
    DEFAULT_PROFILE,
    PROFILE_HELP,
    PROFILES,
    RUN_STEPS,
    T_UP_LIST,
    Plan,
    Run,
    accident_config,
    label_for,
    learners,
    model_label,
    model_name,
    own_profiles,
    run_folder,
    study_out,
    train_config,
)
from coopsumo.studies.scenario1.report import default_study, write_outputs
from coopsumo.studies.scenario1.text import timing_note
from coopsumo.study_tables import SCENARIO1_RUNS, SCENARIO1_SUMMARY
from coopsumo.validation import (
    MOBIL_P_LIST,
    alpha_list,
    default_model_out,
    model_out_dir,
    name_list,
    seed_count,
    steps,
    train_seed_list,
    workers,
)


def _alpha_list(text: str) -> tuple[float, ...]:
    """--alphas: comma-separated alphas (validation.alpha_list; UsageError otherwise); 0 is always part of the study."""
    return tuple(sorted({0.0, *alpha_list("--alphas", text)}))


def _preset_list(text: str) -> tuple[str, ...]:
    return name_list("--preset", text, tuple(learners()))


def _seeds(n: int, _plan: Plan) -> dict[str, Any]:
    if n < 1:
        raise UsageError(f"seeds must be >= 1, got {n}")
    return {"seeds": tuple(range(1, n + 1))}


def _run_steps(n: int, plan: Plan) -> dict[str, Any]:
    """--steps: the accident runs' length, the accident's window scaled with it."""
    if n < 10:
        raise UsageError(f"steps must be >= 10, got {n}")
    scale = n / plan.steps
    return {"steps": n, "accident_start": max(int(plan.accident_start * scale), 1),
            "accident_steps": max(int(plan.accident_steps * scale), 1)}  # fmt: skip


PLAN_FLAGS = (
    PlanFlag(("--seeds",), _seeds, "number of evaluation seeds, 1..N", lambda plan: len(plan.seeds), seed_count),
    PlanFlag(("--train-seeds",),
             lambda text, plan: {"train_seeds": train_seed_list("--train-seeds", text, FIRST_TRAIN_SEED, plan.seeds)},
             f"models per alpha: a count K (training seeds {FIRST_TRAIN_SEED}, {FIRST_TRAIN_SEED + 1}, ...) or a "
             "comma-separated list of training seeds", lambda plan: len(plan.train_seeds)),  # fmt: skip
    PlanFlag(("--t-up",), lambda text, _: {"t_ups": T_UP_LIST.parse("--t-up", text)},
             "demands: T_up (s) of the accident runs, comma-separated, e.g. 3,1.5,1", lambda plan: numbers(plan.t_ups),
             dest="t_ups"),  # fmt: skip
    PlanFlag(("--mobil-p",), lambda text, _: {"mobil_ps": MOBIL_P_LIST.parse("--mobil-p", text)},
             "MOBIL politeness values, comma-separated", lambda plan: numbers(plan.mobil_ps), dest="mobil_ps"),
    PlanFlag(("--train-steps",), at_least("train_steps", "train-steps"), "training steps of each model",
             lambda plan: f"{plan.train_steps:,}", steps),
    PlanFlag(("--steps",), _run_steps, "steps of each accident run; the accident window scales with it",
             lambda plan: f"{plan.steps:,}", RUN_STEPS),
    PlanFlag(("--alphas",), lambda text, _: {"alphas": _alpha_list(text)},
             "alphas to train and run, comma-separated, 0 always included", lambda plan: numbers(plan.alphas)),
    PlanFlag(("--preset", "--presets"), lambda text, _: {"presets": _preset_list(text)},
             "learners, comma-separated, several side by side: the presets default, paper, alpha_only, or a learner "
             "of the catalogue (coopsumo/experiments_data/learners.toml) that drives as saved, e.g. "
             "default,alpha_only_dense", lambda plan: ",".join(plan.presets), dest="presets"),  # fmt: skip
)
"""the flags that set the plan's fields, in the order they apply (--train-seeds reads --seeds')"""


def build_parser() -> Parser:
    p = Parser(prog="coopsumo scenario1", description="Scenario I: the accident bottleneck study.")
    size = p.add_mutually_exclusive_group()  # one way to say the study's size
    size.add_argument("--profile", type=profile_arg(tuple(PROFILES)), default=None,
                      help="the study's sizes: "
                           + "; ".join(f"{k} ({v})" for k, v in PROFILE_HELP.items())
                           + f"; or a profile of your own in a file of scenario1.toml's format, {OWN_PROFILE}")
    size.add_argument("--quick", action="store_true", help="the same as --profile quick")
    size.add_argument("--full", action="store_true", help="the same as --profile full")
    size.add_argument("--regime-map", action="store_true",
                      help="where the accident's queue goes: `keep` only, at the default study's and the paper's "
                           "accident length, at T_up 4, 3, 2.5, 2, 1.5, 1.25 and 1 s (or --t-up), 1 evaluation seed "
                           "(or --seeds), into results/regime_map (or --out); the reason for the default demands "
                           "(until 2026-12-02 `coopsumo regime-map`)")  # fmt: skip
    add_plan_flags(p, PLAN_FLAGS, PROFILES)
    k = len(PROFILES[DEFAULT_PROFILE].train_seeds)
    p.add_argument("--out", type=model_out_dir, default=None,
                   help=f"results folder (default: {by_profile(PROFILES, study_out)}; with --train-seeds K other than "
                        f"{k}: results/scenario1_<K>models, with --preset: results/scenario1_<presets>[_<K>models]; "
                        "only the default profile's report is committed)")  # fmt: skip
    p.add_argument("--workers", type=workers, default=2, help="parallel processes (default 2)")
    add_backend_flags(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--baseline", dest="baselines", action="append", default=None, metavar="POLICY",
                   help="one more policy run beside keep, greedy, MOBIL and sumo, as simulate's --policy takes it (a "
                        "class of your own py:MODULE:CLASS, a Stable-Baselines3 model sb3:PATH, dqn:PATH, ...); "
                        "repeat it for several (default: none; docs/extending.md)")  # fmt: skip
    p.add_argument("--merge", default=None, metavar="P1,P2,...",
                   help="merge finished parts (scenario I study folders of one plan and learner, other training seeds) "
                        "into --out: runs.csv, summary.csv, claim_a.md, report.md (studies/scenario1/merge.py; "
                        "default: none, run a study)")
    return p


def chosen_profile(args: Any) -> Plan:
    """--profile's plan (or --quick's, --full's, else the default): a packaged one by name, or one of a file of one's
    own (PATH.toml[:NAME]: the packaged file's format, every profile checked as the packaged ones are)."""
    text = "quick" if args.quick else "full" if args.full else args.profile or DEFAULT_PROFILE
    return PROFILES[text] if text in PROFILES else own_profile(text, own_profiles, PROFILES, "default")


def plan_from_args(args: Any) -> Plan:
    """The plan of the chosen profile with the command line's overrides applied and checked (UsageError)."""
    plan = plan_from_flags(chosen_profile(args), args, PLAN_FLAGS)
    if getattr(args, "baselines", None):
        plan = replace(plan, baselines=(*plan.baselines, *extra_baselines(args.baselines, plan)))
    return plan


def extra_baselines(texts: list[str], plan: Plan) -> tuple[str, ...]:
    """--baseline's policies, each loaded once here, before anything is written (a module without its class, a
    missing model: UsageError naming it), and each named in the tables apart from every other policy of the plan."""
    import numpy as np

    from coopsumo.agents.policies import make_policy

    taken = {label_for(b) for b in plan.baseline_policies()} | {model_label(p, a) for p in plan.presets
                                                                 for a in plan.alphas}  # fmt: skip
    for text in texts:
        try:
            make_policy(text, np.random.default_rng(0), ControlConfig(), plan.lanes)
        except UsageError as err:
            raise UsageError(f"--baseline {text}: {err}") from None
        if (label := label_for(text)) in taken:
            raise UsageError(f"--baseline {text}: its name in the tables, {label}, is another policy's of the study")
        taken.add(label)
    return tuple(texts)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        if args.regime_map:
            return regime_map.run_from_args(args)
        if args.merge is not None:
            return _merge(args)
        plan = plan_from_args(args)
        if args.workers < 1:
            raise UsageError(f"workers must be >= 1, got {args.workers}")
        check_backend(args.backend, args.address)
        if args.out is None:
            args.out = default_model_out(study_out(plan))
        if (Path(args.out) / "merge.json").exists():
            raise UsageError(f"--out {args.out} holds a merge of scenario I parts (merge.json): pick another --out")
        _check_store_models(plan, Path(args.out))  # before anything is written (issue 82, probe 8, J21)
        # path, lock, ownership (another profile's study refused; its own resumed) and marker of the results folder
        with study_root(args.out, "scenario1", profile_study(plan.profile, presets=plan.presets),
                        recorded_profile("plan.json", "plan", "profile", presets=("plan", "presets")),
                        f"pick another --out (the {plan.profile} profile's default: {study_out(plan)})", trains=True,
                        profile=chosen_profile(args)):
            return run_study(plan, args.out, args.workers, args.backend, args.address, progress=not args.quiet)

    return run_cli("scenario1", body)


def _check_store_models(plan: Plan, out: Path) -> None:
    """UsageError naming the first of the plan's models whose folder in the model store (beside `out`, or
    $COOPSUMO_MODELS) is not a training's to use or write (model_store.check_entry: a link, a user's file in it), before
    the study writes anything; its place and the store's are checked by study_root(trains=True)."""
    from coopsumo.run_dirs import check_out_path, check_study_place
    from coopsumo.studies.engine.model_store import check_entry, model_id

    check_out_path(out)
    check_study_place(out)
    store = store_for(out)
    for preset in plan.presets:
        for alpha in plan.alphas:
            for train_seed in plan.train_seeds:
                check_entry(store / model_id(to_dict(train_config(plan, alpha, preset, train_seed))))


MERGE_ONLY = ("profile", "quick", "full", "regime_map", "seeds", "train_seeds", "t_ups", "mobil_ps", "train_steps",
              "steps", "alphas", "baselines", "presets")
"""the options a merge would ignore (each part's plan holds them): refused beside --merge"""


def _merge(args: Any) -> int:
    from coopsumo.studies.scenario1.merge import merge_parts

    given = [name for name in MERGE_ONLY if getattr(args, name) not in (None, False)]
    if given:
        flag = "--" + given[0].replace("_", "-").replace("t-ups", "t-up").replace("mobil-ps", "mobil-p")
        flag = flag.replace("--baselines", "--baseline").replace("--presets", "--preset")
        raise UsageError(f"--merge takes only --out (the parts' plans hold the rest), got {flag}")
    if args.out is None:
        raise UsageError("--merge needs --out, the merged study's folder")
    parts = [Path(p.strip()) for p in args.merge.split(",") if p.strip()]
    return merge_parts(parts, Path(args.out))


def _cells(plan: Plan, root: Path) -> tuple[list[dict[str, Any]], list[Run]]:
    """Every cell of the study, in the order they start: each model's training into the model store (the longest
    chains; its folder models/<name> a link to the stored model), each model's accident runs (which wait for it:
    "after"), then the baselines'; and every run."""
    store = store_for(root)
    specs: list[dict[str, Any]] = []
    policies: list[tuple[str, str, str | None, int | None]] = []  # (policy, label, its training's key, model seed)
    for preset in plan.presets:
        for alpha in plan.alphas:
            for train_seed in plan.train_seeds:
                name, training = model_name(preset, alpha, train_seed), train_config(plan, alpha, preset, train_seed)
                specs.append({"key": f"train_{name}", "kind": "train", "label": model_label(preset, alpha),
                              "seed": train_seed, "out": f"models/{name}", "training": training,
                              "config": as_data(training), "store": str(store)})  # fmt: skip
                policies.append((f"dqn:{root / 'models' / name / 'model.pt'}", model_label(preset, alpha),
                                 f"train_{name}", train_seed))  # fmt: skip
    policies += [(b, label_for(b), None, None) for b in plan.baseline_policies()]
    runs: list[Run] = []
    for policy, label, after, model_seed in policies:
        for t_up in plan.t_ups:
            for seed in plan.seeds:
                cfg = accident_config(plan, policy, seed, t_up)
                folder = run_folder(label, seed, t_up, model_seed)
                runs.append(Run(label, t_up, seed, root / folder, cfg, model_seed))
                specs.append({"key": runs[-1].key, "kind": "run",
                              "label": label, "seed": seed, "t_up_s": t_up, "out": folder, "after": after,
                              "config": to_dict(cfg), "trajectory_every": plan.trajectory_every,
                              "outputs": to_dict(plan.outputs())})  # fmt: skip
    return specs, runs


def _redone(retrained: set[str], root: Path, specs: list[dict[str, Any]], prog: str) -> set[str]:
    """The cells among `specs` (records reusable) to run again all the same (a cells.Check): the trainings of
    `retrained` (models the store does not hold whole), their models' runs, and every run whose folder is not
    reusable (accident_runs.folder_reusable, with the model or module file its policy drives as it is now)."""
    return {s["key"] for s in specs if s["key"] in retrained or s.get("after") in retrained
            or (s["kind"] == "run" and not folder_reusable(root, s, prog, model=True))}  # fmt: skip


def _runs_table(plan: Plan, runs: list[Run]) -> pd.DataFrame:
    """One row per run, demands from the highest, policies in the plan's order."""
    sample_s = plan.trajectory_every * ControlConfig().dt_s
    order = {lab: i for i, lab in enumerate(dict.fromkeys(r.label for r in runs))}
    rows = pd.DataFrame([{"t_up_s": r.t_up, "policy": r.label, "train_seed": r.train_seed, "seed": r.seed,
                          **run_metrics(r.out, r.cfg, sample_s)} for r in runs])  # fmt: skip
    rows["train_seed"] = rows["train_seed"].astype("Int64")  # empty for a baseline
    return rows.sort_values(["t_up_s", "policy", "train_seed", "seed"], ascending=[False, True, True, True],
                            key=lambda c: c.map(order) if c.name == "policy" else c, kind="stable",
                            ignore_index=True)  # fmt: skip


def run_study(plan: Plan, root: Path, workers: int = 2, backend_name: str = "local", address: str | None = None,
              progress: bool = True) -> int:  # fmt: skip
    """Run (or finish) the study of `plan` in root on the shared study engine (engine/cells.Study: the cells still to
    run, the trainings first and as groups on the local backend) and write its outputs; its exit code."""
    start = time.perf_counter()
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write {root}: {err.strerror}") from None
    if (beside := default_study(root, plan)) is not None:  # the report reads its runs.csv: refused now, not at the end
        SCENARIO1_RUNS.read(beside / "runs.csv")
    settings = {preset: to_dict(learners()[preset]) for preset in plan.presets}  # the report's learner settings
    write_json(root / "plan.json", {"plan": to_dict(plan), "learners": settings, "versions": versions()})
    specs, runs = _cells(plan, root)
    trains = [s for s in specs if s["kind"] == "train"]  # a stored model is linked, never trained again
    retrained = {s["key"] for s in trains if stored_model(s["config"], Path(s["store"]), root / s["out"]) is None}
    print(f"scenario1: {len(trains) - len(retrained)} of {len(trains)} models from the model store "
          f"{store_for(root)}; {len(retrained)} trainings to run", file=sys.stderr)  # fmt: skip
    ran: dict[str, int] = {}  # how many accident runs the engine found still to run (its order's count)
    study = Study("scenario1", CELLS, REQUIRED, places, lambda todo: ran.update(runs=sum(s["kind"] == "run"
                                                                                      for s in todo)),
                  checks=(partial(_redone, retrained),))  # fmt: skip
    meta = study.run(specs, root, {}, plan.profile, partial(_finish, plan, root, runs, trains, len(retrained), ran,
                                                            start), workers=workers, backend=backend_name,
                     address=address, roads=[RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s)],
                     progress=progress)  # fmt: skip
    if meta["failed_cells"]:
        return failed_exit("scenario1", meta["failed_cells"], len(specs), root)
    print(f"scenario1: done in {(time.perf_counter() - start) / 60:.1f} min; report: {root / 'report.md'}")
    return 0


def _finish(plan: Plan, root: Path, runs: list[Run], trains: list[dict[str, Any]], trained: int, ran: dict[str, int],
            start: float, records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    """runs.csv, summary.csv, the figures and report.md of the study when none of its cells failed (both tables
    checked inside their limits before either is written); the report's timing counts the `trained` models and
    ran["runs"] accident runs this invocation ran."""
    if meta["failed_cells"]:
        return
    rows = _runs_table(plan, runs)
    SCENARIO1_RUNS.check_frame(rows, root / "runs.csv")
    SCENARIO1_SUMMARY.check_frame(aggregate(rows), root / "summary.csv")
    write_atomic(root / "runs.csv", lambda tmp: rows.to_csv(tmp, index=False))
    cpu: dict[str, Any] = {r["key"]: r.get("cell_cpu_s") for r in records}  # each demand's accident runs' CPU seconds
    run_cpu = {t: [float(cpu[r.key]) for r in runs if r.t_up == t and cpu[r.key] is not None] for t in plan.t_ups}
    timing = timing_note(time.perf_counter() - start, len(trains) - trained, len(trains), len(runs) - ran["runs"],
                         len(runs), [root / s["out"] / "train_summary.json" for s in trains], run_cpu)  # fmt: skip
    write_outputs(root, plan, rows, runs, timing)


if __name__ == "__main__":
    sys.exit(main())
