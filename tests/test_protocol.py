"""The learner protocol (`coopsumo protocol`): a tiny profile in SUMO end to end, and its bad input."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from conftest import committed_report_pages, main_here

from coopsumo.studies.protocol.report import VALIDATION_CAPTION

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.sumo
def test_an_alpha_conditioned_variant_trains_once_and_drives_at_each_cells_alpha(tmp_path: Path) -> None:
    """The c2x variant: one conditioned training per seed (its world's alpha 0) for its alpha 0 and alpha 8 cells, each
    driven at its own alpha; the report is written."""
    from dataclasses import replace

    from coopsumo.studies.engine.cells import cell_policy
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs
    from coopsumo.studies.protocol.study import run_study

    profile = replace(PROFILES["tiny"], name="tiny_c2x", variants=("c2x",), seeds=(PROFILES["tiny"].seeds[0],),
                      t_ups=(1.0,))  # fmt: skip
    specs = [s for s in cell_specs(profile) if s["kind"] == "model"]
    assert {s["alpha"] for s in specs} == {0.0, 8.0}
    assert len({str(s["config"]["train"]) for s in specs}) == 1  # one training for both alphas
    assert {cell_policy(s, Path("/m/model.pt")).rsplit(",", 1)[-1] for s in specs} == {"alpha=0", "alpha=8"}
    assert PROFILES["c2x"].train_steps == PROFILES["nr10_180k"].train_steps == 180_000
    out = tmp_path / "proto"
    run_study(profile, out, workers=2, progress=False)
    runs = pd.read_csv(out / "runs.csv")
    assert (runs["status"] == "ok").all() and set(runs[runs["kind"] == "model"]["alpha"]) == {0.0, 8.0}
    assert (runs["collisions"] == 0).all() and (runs["teleports"] == 0).all()
    assert "## Free flow" in (out / "report.md").read_text()


@pytest.mark.sumo
def test_tiny_protocol_runs_reports_and_reuses(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The tiny study as a process, as a user runs it; its reruns, which judge what it left, by protocol's main in
    this process (its workers' output captured too)."""
    from coopsumo.studies.protocol import study as protocol

    out = tmp_path / "proto"
    cmd = [sys.executable, "-m", "coopsumo", "protocol", "--profile", "tiny", "--out", str(out), "--quiet"]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    runs = pd.read_csv(out / "runs.csv")
    assert (runs["status"] == "ok").all() and len(runs) == 30
    # both learners drive the models of one training per seed; each model met every condition on the same seeds
    models = runs[runs["kind"] == "model"]
    assert models.groupby(["scenario", "t_up"])["eval_seed"].nunique().eq(1).all()
    assert set(models["weights"]) == {"model.pt", "model_last.pt"}
    assert models[models["alpha"] == 0]["train_key"].nunique() == 2
    acc = runs[runs["scenario"] == "accident"]
    assert (acc["tts_veh_h"] > 0).all() and acc["queue_lane_changes_per_vehicle"].ge(0).all()
    assert runs[runs["scenario"] == "free"]["queue_lane_changes_per_vehicle"].isna().all()  # an accident measure
    assert (runs["collisions"] == 0).all() and (runs["teleports"] == 0).all()
    table = pd.read_csv(out / "stats.csv")
    assert len(table) == 2 * 2 * 2  # scenarios x demands x learners
    assert ((table["low"] <= table["iqm"]) & (table["iqm"] <= table["high"])).all()
    assert table["keep_poi"].between(0, 1).all()
    report = (out / "report.md").read_text()
    assert "## Free flow" in report and "## Targets for `select`" in report and "## Diagnosis" in report
    assert "### Thrashing: lane changes in the queue" in report
    free = runs[runs["scenario"] == "free"]  # every run records its passing chances; keep never takes one
    assert free["held_share"].between(0, 1).all() and "## Passing in free flow" in report
    assert (free[free["variant"] == "keep"]["passing_taken_share"].fillna(0) == 0).all()
    assert (out / "fig_validation.png").exists() and (out / "diagnosis.csv").exists()
    assert f"![validation over training](fig_validation.png)\n\n{VALIDATION_CAPTION}\n" in report  # captioned
    code, _, err = main_here(protocol.main, cmd[4:], capfd)
    assert code == 0 and "30 already done" in err, err[-2000:]
    # issue 82, fifth probe, G8: a training whose validation.csv holds a score of 1e9 was copied into diagnosis.csv;
    # it is trained again, with one line naming the file and the field, and only the cells of that training run again
    val = sorted((out / "train").glob("*/validation.csv"))[0]
    lines = val.read_text().splitlines(keepends=True)
    val.write_text("".join([lines[0], lines[1].split(",", 2)[0] + ",1e9," + lines[1].split(",", 2)[2], *lines[2:]]))
    code, _, err = main_here(protocol.main, cmd[4:], capfd)
    assert code == 0 and "Traceback" not in err, err[-2000:]
    assert f"protocol: {val} has score = '1e9' in its row of step " in err, err[-2000:]
    assert "; training it again" in err and "30 already done" not in err
    assert "1e+09" not in (out / "diagnosis.csv").read_text() and ",1e9," not in val.read_text()


def test_every_committed_protocol_report_captions_its_validation_figure() -> None:
    """fig_validation.png had no caption: the report says under it what it draws, as the committed reports do."""
    pages = [p for p in committed_report_pages() if p.parent.name.startswith("learner_protocol")]
    assert pages and "training seed" in VALIDATION_CAPTION and "(middle)" in VALIDATION_CAPTION
    for page in pages:
        text = page.read_text()
        if "fig_validation.png" in text:
            assert f"![validation over training](fig_validation.png)\n\n{VALIDATION_CAPTION}\n" in text, page


@pytest.mark.parametrize("args, fragment", [(["--profile", "huge"], "--profile"), (["--workers", "0"], "--workers")])
def test_bad_protocol_input_is_one_line(tmp_path: Path, args: list[str], fragment: str) -> None:
    out = tmp_path / "proto"
    res = subprocess.run([sys.executable, "-m", "coopsumo", "protocol", "--out", str(out), *args], cwd=ROOT,
                         capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in res.stderr
    assert not out.exists()


DRIVEN = """
[nr10]
preset = "default"
status = "default"
why = "the default"

[m2]
parent = "nr10"
status = "tried"
why = "driven with a change margin of 2"
drive = { change_margin = 2 }

[nr5]
parent = "nr10"
status = "tried"
why = "driven with 5 s without the change back"
drive = { no_return_s = 5 }

[nr10_off]
parent = "nr10"
status = "tried"
why = "the same trainings without the change back when they drive"
drive = { no_return_s = 0.0 }

[lanes]
parent = "nr5"
status = "tried"
why = "lanes only, and the no-return window of its parent"
drive = { restart_below_mps = 50.0, queue_below_mps = 5.0 }

[other]
parent = "nr10"
status = "tried"
why = "another training: a discount of 0.95"
learner = { gamma = 0.95 }
"""


def driven_catalogue(tmp_path: Path) -> dict[str, Any]:
    from coopsumo.studies.protocol.plan import load_variants

    (tmp_path / "learners.toml").write_text(DRIVEN)
    return load_variants(tmp_path / "learners.toml")


def test_a_trainings_other_cells_wait_for_its_first() -> None:
    """A model shared by many cells (the drive variants', a conditioned network's alphas, the demands) is trained
    by its first cell; every other cell of it names that cell (after: the runner gives a free worker another cell
    meanwhile, not one that would wait on the training's lock; the conditioned profile's one lone training held both
    workers)."""
    from coopsumo.studies.engine.model_store import model_id
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs

    specs = cell_specs(PROFILES["conditioned"])
    firsts: dict[str, str] = {}
    for spec in specs:
        if spec["train_key"] is None:
            assert "after" not in spec
        elif (first := firsts.setdefault(model_id(spec["config"]["train"]), spec["key"])) == spec["key"]:
            assert "after" not in spec, spec["key"]
        else:
            assert spec["after"] == first, spec["key"]
    assert len(firsts) == 30 and sum("after" in s for s in specs) == sum(s["kind"] == "model" for s in specs) - 30


def test_a_drive_variant_drives_the_same_training_its_own_way(tmp_path: Path) -> None:
    """A variant with a `drive` table shares its parent's trainings (the same train_key and training config) and
    records how it drives in its cells (another record); a child inherits its parent's drive; the judged variant's
    alpha-8 models are its own, and a learner change is another training."""
    from dataclasses import replace

    from coopsumo.policy_spec import parse_policy
    from coopsumo.studies.engine.cells import cell_policy
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs

    known = driven_catalogue(tmp_path)
    profile = replace(PROFILES["nr10"], name="drive", variants=tuple(known), judged="m2")
    specs = {s["key"]: s for s in cell_specs(profile, known)}
    own, m2 = specs["nr10_a0_seed100_accident_t1"], specs["m2_a0_seed100_accident_t1"]
    assert own["train_key"] == m2["train_key"] and own["config"]["train"] == m2["config"]["train"]
    assert "drive" not in own["config"] and m2["config"]["drive"] == {"change_margin": 2.0}  # a different record
    assert parse_policy(cell_policy(own, Path("/m/model.pt"))).margin is None  # the margin the model was saved with
    assert parse_policy(cell_policy(m2, Path("/m/model.pt"))).margin == 2.0
    drives = {s["variant"]: parse_policy(cell_policy(s, Path("/m/model.pt"))) for s in specs.values()
              if s["key"].endswith("a0_seed104_free_t2")}  # fmt: skip
    assert drives["nr5"].noreturn == 5.0 and drives["nr5"].margin is None
    assert drives["nr10_off"].noreturn == 0.0 and drives["nr10"].noreturn is None
    assert (drives["lanes"].restart, drives["lanes"].queue, drives["lanes"].noreturn) == (50.0, 5.0, 5.0)
    keys = {s["variant"]: s["train_key"] for s in specs.values() if s["seed"] == 105 and s["alpha"] == 0.0}
    assert len({k for v, k in keys.items() if v != "other"}) == 1 and keys["other"] != keys["nr10"]
    alpha8 = [s for s in specs.values() if s["alpha"] == 8.0]
    assert {s["variant"] for s in alpha8} == {"m2"} and {s["scenario"] for s in alpha8} == {"free"}
    assert len({s["train_key"] for s in alpha8}) == profile.alpha_seeds


def test_paired_rows_compare_the_same_trainings_model_by_model() -> None:
    from coopsumo.studies.protocol.report import paired_rows

    rows = []
    for seed, (own, m2) in enumerate([(40.0, 38.0), (42.0, 41.0), (39.0, 39.5)]):
        for variant, tts, lcs in (("v2x_mix", own, 3.0), ("v2x_mix_m2", m2, 1.0)):
            rows.append({"status": "ok", "alpha": 0.0, "scenario": "accident", "t_up": 1.5, "variant": variant,
                         "seed": 100 + seed, "train_key": f"k{seed}", "tts_veh_h": tts,
                         "lane_changes_per_vehicle": lcs})  # fmt: skip
    (row,) = paired_rows(pd.DataFrame(rows), "v2x_mix_m2", "v2x_mix")
    assert row["models"] == 3 and row["better"] == 2  # lower total time spent is better
    assert row["diff"] == pytest.approx((-2.0 - 1.0 + 0.5) / 3) and row["low"] < row["diff"] < row["high"]
    assert row["lane_changes"] == pytest.approx(-2.0)


def test_the_passing_section_shows_each_policy_and_is_left_out_for_runs_without_it() -> None:
    from coopsumo.studies.protocol.plan import Profile
    from coopsumo.studies.protocol.report import passing_lines

    profile = Profile("p", variants=("f05q",))
    rows = [{"status": "ok", "alpha": 0.0, "scenario": "free", "t_up": 2.0, "variant": v, "held_share": h,
             "passing_open_share": o, "passing_taken_share": t}
            for v, h, o, t in (("f05q", 0.30, 0.10, 0.06), ("f05q", 0.32, 0.12, 0.08), ("keep", 0.55, 0.36, 0.0))]
    lines = passing_lines(pd.DataFrame(rows), profile)
    assert "| 2 | `f05q` | 2 | 0.310 | 0.110 | 0.07 |" in lines and "| 2 | `keep` | 1 | 0.550 | 0.360 | 0.00 |" in lines
    old = pd.DataFrame(rows).assign(held_share=math.nan, passing_open_share=math.nan, passing_taken_share=math.nan)
    assert passing_lines(old, profile) == []  # runs made before the measure: no section


@pytest.mark.sumo
def test_the_thrashing_measure_is_scenario_ones_on_the_same_run(tmp_path: Path) -> None:
    """An accident run's queue lane changes per vehicle (and total time spent) as the protocol records them equal
    scenario I's measures of the same run (run_metrics: bottleneck.queue_lane_changes on its trajectories): the same
    sampling and the same 5 m/s. Greedy at T_up 1 s changes lanes in the queue, so the count is not a trivial 0."""
    import json
    from dataclasses import replace

    from coopsumo.config import to_dict
    from coopsumo.report import bottleneck as bn
    from coopsumo.studies.engine.run_folders import simulate_into
    from coopsumo.studies.protocol.plan import PROFILES, QUEUE_MPS, TRAJECTORY_EVERY, eval_config
    from coopsumo.studies.protocol.study import accident_measures
    from coopsumo.studies.scenario1 import plan as scenario1_plan
    from coopsumo.studies.scenario1.measures import SLOW_MPS, run_metrics

    assert QUEUE_MPS == SLOW_MPS and TRAJECTORY_EVERY == scenario1_plan.PROFILES["default"].trajectory_every
    profile = replace(PROFILES["tiny"], accident_steps=2000, accident_start=100, accident_duration=1500)
    cfg = eval_config(profile, "accident", profile.t_ups.index(1.0), "greedy")
    out = tmp_path / "run"
    summary = simulate_into(json.loads(json.dumps(to_dict(cfg))), out, "run", trajectory_every=TRAJECTORY_EVERY)
    ours = accident_measures(out, cfg, summary["departed"])
    theirs = run_metrics(out, cfg, TRAJECTORY_EVERY * cfg.control.dt_s)
    queue = bn.queue_lane_changes(pd.read_parquet(out / "trajectories.parquet"), 5.0)
    assert queue > 0 and ours["queue_lane_changes_per_vehicle"] == queue / summary["departed"]
    assert ours == {k: theirs[k] for k in ("tts_veh_h", "queue_lane_changes_per_vehicle")}


def test_the_thrashing_table_counts_models_and_says_n_a_for_runs_without_the_measure() -> None:
    """Per demand and learner: the median and range of the models' queue lane changes per vehicle and how many
    thrash (0.5 or more); the baselines' values; a committed runs.csv from before the measure reads n/a."""
    from coopsumo.studies.protocol.plan import Profile
    from coopsumo.studies.protocol.report import per_model
    from coopsumo.studies.protocol.thrashing import thrashing_lines

    profile = Profile("p", variants=("a", "b"))
    rows = [{"key": f"{v}{seed}{e}", "kind": "model", "variant": v, "alpha": 0.0, "seed": seed, "scenario": "accident",
             "t_up": 1.5, "eval_seed": 5101 + e, "weights": "model.pt", "status": "ok", "tts_veh_h": 60.0,
             "queue_lane_changes_per_vehicle": q + e * 0.25}
            for v, qs in (("a", (0.125, 0.375, 1.875)), ("b", (0.125, 0.25, 0.25))) for seed, q in enumerate(qs, 100)
            for e in (0, 1)]  # fmt: skip
    rows += [{"key": f"{b}{e}", "kind": "baseline", "variant": b, "alpha": 0.0, "scenario": "accident", "t_up": 1.5,
              "eval_seed": 5101 + e, "status": "ok", "queue_lane_changes_per_vehicle": q}
             for b, q in (("keep", 0.0), ("greedy", 0.8), ("mobil:p=0", 0.3)) for e in (0, 1)]  # fmt: skip
    runs = pd.DataFrame(rows)
    lines = thrashing_lines(per_model(runs), profile)
    # a: model means 0.25, 0.5, 2 (two thrash: 0.5 counts); b: 0.25, 0.375, 0.375 (none)
    assert "| 1.5 | `a` | 3 | 0.50 [0.25, 2.00] | 2 of 3 | 0.00 | 0.80 | 0.30 |" in lines
    assert "| 1.5 | `b` | 3 | 0.38 [0.25, 0.38] | 0 of 3 | 0.00 | 0.80 | 0.30 |" in lines
    old = per_model(runs.drop(columns="queue_lane_changes_per_vehicle"))
    assert "| 1.5 | `a` | 3 | n/a | n/a | n/a | n/a | n/a |" in thrashing_lines(old, profile)


def test_a_rounded_copy_of_the_same_run_is_not_counted_better() -> None:
    """A committed runs.csv keeps 6 significant digits: the same run read back differs by about 1e-6 and is a tie,
    not a model that did better; a real difference in the 5th digit still counts."""
    from coopsumo.studies.protocol.report import paired_rows

    rows = []
    for seed, (own, copy) in enumerate([(20.1234567, 20.1235), (19.87654321, 19.8765), (20.5, 20.499)]):
        for variant, speed in (("f05q", own), ("committed", copy)):
            rows.append({"status": "ok", "alpha": 0.0, "scenario": "free", "t_up": 2.0, "variant": variant,
                         "seed": 100 + seed, "tts_veh_h": 0.0, "mean_speed_mps": speed,
                         "lane_changes_per_vehicle": 1.0})  # fmt: skip
    (row,) = paired_rows(pd.DataFrame(rows), "f05q", "committed")
    assert row["models"] == 3 and row["better"] == 1  # only seed 102 (+0.001 m/s) is better


def test_a_variant_that_only_chooses_snapshots_otherwise_is_paired_by_model() -> None:
    """nr10's trainings are f05q_ts2k's judged again (no change back when snapshots are chosen; another train_key):
    paired by model; another learner's trainings on the same seeds (select) are paired by training seed in a section
    of their own."""
    from coopsumo.config import to_dict
    from coopsumo.studies.protocol.plan import Profile, variants
    from coopsumo.studies.protocol.report import paired_lines

    known = variants()
    rows = [{"status": "ok", "alpha": 0.0, "scenario": "free", "t_up": 2.0, "variant": v, "seed": seed,
             "train_key": f"{v}{seed}", "mean_speed_mps": speed + (0.5 if v == "nr10" else 0.0),
             "lane_changes_per_vehicle": 1.0} for v in ("f05q_ts2k", "nr10", "select")
            for seed, speed in ((100, 20.0), (101, 21.0))]  # fmt: skip
    learners = {v: {"learner": to_dict(known[v].learner)} for v in ("f05q_ts2k", "nr10", "select")}
    profile = Profile("x", variants=("f05q_ts2k", "nr10", "select"))
    text = "\n".join(paired_lines(pd.DataFrame(rows), profile, {"learners": learners}))
    same, other = text.split("## Other trainings on the same training seeds")
    assert "## The same trainings driven or chosen otherwise" in same
    assert "| `nr10` | free | 2 | +0.50" in same and "2 of 2" in same and "`select` |" not in same
    # another learner's trainings: paired by training seed in a section of their own
    assert "| `select` | free | 2 | +0.00" in other and "`nr10` |" not in other


def test_fresh_evaluation_seeds_drive_the_same_trainings() -> None:
    """A profile with another evaluation seed offset replicates nr10 on seeds that no other study, training or
    validation uses, with the same trainings."""
    from dataclasses import replace

    from coopsumo.dqn_config import VALIDATION_SEED
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs

    ours = cell_specs(replace(PROFILES["nr10"], name="nr10_e1", eval_offsets=(10,), alpha_seeds=0))
    theirs = cell_specs(PROFILES["nr10"])
    trainings = {s["train_key"]: s["config"]["train"] for s in theirs if s["kind"] == "model"}
    assert all(trainings[s["train_key"]] == s["config"]["train"] for s in ours if s["kind"] == "model")
    seeds, before = {s["eval_seed"] for s in ours}, {s["eval_seed"] for s in theirs}
    assert seeds == {5010, 5011, 5012, 5110, 5111, 5112} and not seeds & before
    assert not seeds & set(PROFILES["nr10"].seeds) and min(seeds) < VALIDATION_SEED


def test_the_current_profile_judges_the_default_and_nr10_measured_its_alpha_response() -> None:
    """stks judges today's default (the profile that adopted it); nr10's profile, the default's before, measured
    alpha 8 on 3 of its seeds in free flow."""
    from coopsumo.dqn_config import DQNConfig
    from coopsumo.studies.protocol.plan import CURRENT, PROFILES, cell_specs, variants

    profile = PROFILES[CURRENT]
    assert CURRENT == "stks" and profile.judged_variant() == "stks" and variants()["stks"].learner == DQNConfig()
    before = PROFILES["nr10"]
    alpha8 = [s for s in cell_specs(before) if s.get("alpha") == 8.0]
    assert alpha8 and {s["variant"] for s in alpha8} == {"nr10"}
    assert {s["scenario"] for s in alpha8} == {"free"} and len({s["train_key"] for s in alpha8}) == before.alpha_seeds


def test_a_committed_studys_trainings_pair_only_when_made_the_same_way(tmp_path: Path) -> None:
    """Profile.paired_with: a committed study's variant on the same training and evaluation seeds is paired by
    training seed; another learner, other evaluation seeds or another profile are refused with the reason."""
    import json
    from dataclasses import asdict, replace

    from coopsumo.config import to_dict
    from coopsumo.studies.protocol.plan import Profile, variants
    from coopsumo.studies.protocol.report import committed_pair_lines

    def rows(variant: str, speeds: tuple[float, ...], eval_seed: int = 5000) -> list[dict[str, object]]:
        return [{"key": f"{variant}{seed}", "kind": "model", "variant": variant, "alpha": 0.0, "seed": seed,
                 "scenario": "free", "t_up": 2.0, "eval_seed": eval_seed, "status": "ok", "mean_speed_mps": v,
                 "lane_changes_per_vehicle": 1.0} for seed, v in zip((100, 101), speeds, strict=True)]  # fmt: skip

    profile = Profile("x", variants=("nr10",), seeds=(100, 101),
                      paired_with=(("nr10", "learner_protocol_old", "f05q_ts2k"),))  # fmt: skip
    runs = pd.DataFrame(rows("nr10", (20.0, 21.0)))
    folder = tmp_path / "learner_protocol_old"
    folder.mkdir()
    learners = {"f05q_ts2k": {"learner": to_dict(variants()["f05q_ts2k"].learner), "weights": "model.pt"}}
    old = Profile("old", variants=("f05q_ts2k",))

    def commit(study_profile: Profile, eval_seed: int = 5000, learner_lr: float | None = None) -> str:
        entry = dict(learners["f05q_ts2k"])
        if learner_lr is not None:
            entry["learner"] = {**entry["learner"], "lr": learner_lr}  # type: ignore[dict-item]
        study = {"profile": asdict(study_profile), "learners": {"f05q_ts2k": entry}}
        (folder / "study.json").write_text(json.dumps(study))
        pd.DataFrame(rows("f05q_ts2k", (19.5, 20.0), eval_seed)).to_csv(folder / "runs.csv", index=False)
        return "\n".join(committed_pair_lines(runs, profile, tmp_path))

    text = commit(replace(old, seeds=(100, 101)))
    assert "| `nr10` | `f05q_ts2k` ([learner_protocol_old]" in text and "| +0.75 [" in text
    assert "2 of 2" in text and "not paired" not in text
    assert "not paired, its f05q_ts2k is not today's" in commit(replace(old, seeds=(100, 101)), learner_lr=0.5)
    assert "not paired, other evaluation seeds (free, T_up 2 s)" in commit(old, eval_seed=5007)
    assert "not paired, its profile differs in train_steps" in commit(replace(old, train_steps=1000))
    (folder / "runs.csv").unlink()
    assert "not paired, no runs.csv and study.json in learner_protocol_old" in "\n".join(
        committed_pair_lines(runs, profile, tmp_path))


def test_several_evaluation_seed_sets_judge_each_model_by_its_mean() -> None:
    """nr10_3sets meets every condition on 3 seeds: the first set's cells are nr10's (reused), and the statistics
    compare each model's mean over the sets with the baselines' mean over the same seeds."""
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs
    from coopsumo.studies.protocol.report import condition_stats, per_model

    three, one = cell_specs(PROFILES["nr10_3sets"]), cell_specs(PROFILES["nr10"])
    first = {s["key"]: s for s in one if s.get("alpha") == 0.0}
    assert all(first[s["key"]]["config"] == s["config"] for s in three if s["key"] in first)
    assert len(three) == 3 * len(first) and len({s["key"] for s in three}) == len(three)
    free_t2 = {s["eval_seed"] for s in three if s["scenario"] == "free" and s["t_up"] == 2.0}
    assert free_t2 == {5000, 5020, 5040}
    # a model below keep on one seed and above it on average is not a loss; the mean decides
    rows = []
    for eval_seed, own, keep in ((5000, 17.0, 18.0), (5020, 20.0, 18.5), (5040, 21.0, 18.5)):
        for variant, kind, seed, speed in (("m", "model", 100.0, own), ("keep", "baseline", math.nan, keep)):
            rows.append({"key": f"{variant}{eval_seed}", "kind": kind, "variant": variant, "alpha": 0.0,
                         "seed": seed, "scenario": "free", "t_up": 2.0, "eval_seed": eval_seed, "status": "ok",
                         "weights": "model.pt" if kind == "model" else None, "mean_speed_mps": speed,
                         "lane_changes_per_vehicle": 1.0, "collisions": 0.0, "teleports": 0.0})  # fmt: skip
    models = per_model(pd.DataFrame(rows))
    assert len(models) == 2 and set(models["eval_runs"]) == {3} and set(models["eval_seed"]) == {5000}
    assert models.set_index("variant").loc["m", "mean_speed_mps"] == pytest.approx(58.0 / 3)
    (row,) = condition_stats(models, ["m"], ["keep"]).to_dict("records")
    assert row["keep_value"] == pytest.approx(55.0 / 3) and row["keep_losses"] == 0
    (one_set,) = condition_stats(per_model(pd.DataFrame(rows[:2])), ["m"], ["keep"]).to_dict("records")
    assert one_set["keep_losses"] == 1  # judged on the first seed alone, the same model lost
