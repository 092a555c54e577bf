"""Claim (a)'s analysis plan (coopsumo/studies/scenario1/claim_a.py, issue 78 step 2) on tables with known answers:
the co-primary comparisons decide a planted effect and leave a null one undecided, Holm's adjusted p-values and the
power computation match their definitions, the mechanism counts thrashing models, and the plan's number of models
follows its rule; claim_a.md and fig_thrashing.png are written from a table of runs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from coopsumo.studies.scenario1 import claim_a
from coopsumo.studies.scenario1.claim_a_report import write_claim_a

A8, A0 = "dqn_x_alpha8", "dqn_x_alpha0"


def runs_table(models: int = 12, tts_effect: float = -5.0, seed: int = 0, thrash8: int = 2,
               thrash0: int = 8) -> pd.DataFrame:  # fmt: skip
    """A scenario I runs.csv: two demands, `models` models per alpha x 5 seeds, keep; alpha 8's total time spent
    lower by -tts_effect (model spread 1 veh-h), recovery and waves the same in law for both alphas; the first
    thrash8 / thrash0 models of each alpha thrash (2 queue lane changes per vehicle, else 0.1)."""
    rng = np.random.default_rng(seed)
    rows = []
    for t_up in (2.0, 1.0):
        for label, shift, thrash in ((A0, 0.0, thrash0), (A8, tts_effect, thrash8)):
            for m in range(models):
                model_tts = 50 + shift + rng.normal(0, 1.0)
                for s in range(1, 6):
                    rows.append({"t_up_s": t_up, "policy": label, "train_seed": 100 + m, "seed": s,
                                 "tts_veh_h": model_tts + rng.normal(0, 0.5),
                                 "system_recovery_s": float(rng.normal(600, 100)) if s != 5 else math.nan,
                                 "horizon_after_start_s": 1800.0, "waves": float(rng.poisson(2)),
                                 "queue_lane_changes_per_vehicle": 2.0 if m < thrash else 0.1})  # fmt: skip
        for s in range(1, 6):
            rows.append({"t_up_s": t_up, "policy": "keep", "train_seed": math.nan, "seed": s, "tts_veh_h": 52.0,
                         "system_recovery_s": 700.0, "horizon_after_start_s": 1800.0, "waves": 1.0,
                         "queue_lane_changes_per_vehicle": 0.0})  # fmt: skip
    return pd.DataFrame(rows)


def test_a_planted_effect_is_decided_and_a_null_one_is_not() -> None:
    table = claim_a.comparisons(runs_table(), A8, A0)
    assert len(table) == 6 and set(table["measure"]) == set(claim_a.CO_PRIMARY)
    tts = table[table["measure"] == "tts_veh_h"]
    assert (tts["verdict"] == "helps").all() and (tts["hi"] < 0).all() and (tts["lower"] == 12).all()
    assert tts["diff"].between(-6.5, -3.5).all()
    nulls = table[table["measure"] != "tts_veh_h"]
    assert (nulls["verdict"] == "cannot decide").all()
    hurting = claim_a.comparisons(runs_table(tts_effect=+5.0), A8, A0)
    assert (hurting[hurting["measure"] == "tts_veh_h"]["verdict"] == "hurts").all()
    assert (claim_a.comparisons(runs_table(models=2), A8, A0)["verdict"] == "cannot decide").all()  # < 3 models


def test_a_run_that_never_recovers_counts_as_its_horizon() -> None:
    rows = runs_table()
    rows.loc[rows["policy"] == A8, "system_recovery_s"] = math.nan  # alpha 8 never recovers: 1800 s everywhere
    rec = claim_a.comparisons(rows, A8, A0).set_index(["t_up_s", "measure"]).loc[(1.0, "system_recovery_s")]
    # alpha 0: 4 of 5 seeds near 600 s, the fifth never (1800): 840 s on average; alpha 8: 1800 s
    assert rec["diff"] == pytest.approx(1800 - 840, abs=60) and rec["verdict"] == "hurts"


def test_holm_adjusted_p_values_follow_the_step_down_definition() -> None:
    p = pd.Series([0.04, 0.01, 0.03], index=["a", "b", "c"])
    adjusted = claim_a.holm_adjusted(p)
    assert adjusted.to_dict() == pytest.approx({"b": 0.03, "c": 0.06, "a": 0.06})
    assert claim_a.holm_adjusted(pd.Series([0.5, 0.6])).tolist() == pytest.approx([1.0, 1.0])


def test_the_power_of_the_t_test_matches_a_simulation() -> None:
    rng = np.random.default_rng(3)
    from scipy.stats import ttest_1samp

    for effect, sd, n, level in ((1.0, 2.0, 20, 0.05), (0.5, 1.0, 30, 0.05 / 9)):
        samples = rng.normal(effect, sd, size=(4000, n))
        simulated = float(np.mean(ttest_1samp(samples, 0.0, axis=1).pvalue < level))
        assert claim_a.power(effect, sd, n, level) == pytest.approx(simulated, abs=0.03)
    needed = claim_a.models_for_power(1.0, 1.5, 0.05)
    assert needed is not None and claim_a.power(1.0, 1.5, needed, 0.05) >= 0.9 > claim_a.power(1.0, 1.5, needed - 1,
                                                                                                 0.05)  # fmt: skip
    assert claim_a.models_for_power(0.01, 10.0, 0.05) is None
    assert claim_a.detectable_effect(1.5, needed, 0.05) == pytest.approx(1.0, rel=0.15)


def test_thrashing_models_are_counted_per_alpha_and_tested() -> None:
    tests = claim_a.thrashing_tests(runs_table(thrash8=1, thrash0=11), A8, A0)
    assert tests[["thrash_a", "models_a", "thrash_b", "models_b"]].values.tolist() == [[1, 12, 11, 12]] * 2
    assert (tests["p"] < 0.001).all() and (tests["p_holm"] >= tests["p"]).all()
    same = claim_a.thrashing_tests(runs_table(thrash8=5, thrash0=5), A8, A0)
    assert (same["p"] == 1.0).all()


def test_the_plan_runs_the_fewest_models_that_decide_one_measure_at_two_demands() -> None:
    def pilot(needed: list[int | None]) -> pd.DataFrame:
        return pd.DataFrame({"measure": ["tts_veh_h", "tts_veh_h", "waves", "waves"], "needed": needed})

    assert claim_a.planned_models(pilot([12, 25, 5, None])) == 25
    assert claim_a.planned_models(pilot([5, 8, None, None])) == claim_a.MIN_PLANNED
    assert claim_a.planned_models(pilot([5, None, 8, None])) == claim_a.MAX_MODELS  # no measure at two demands
    rows = runs_table(models=12)
    first = claim_a.pilot(rows, A8, A0)
    assert (first["models"] == claim_a.PILOT_MODELS).all()
    assert claim_a.planned_models(first) == claim_a.MIN_PLANNED  # the planted 5 veh-h on a 1 veh-h spread


def test_claim_a_md_and_the_thrashing_figure_are_written(tmp_path: Path) -> None:
    write_claim_a(tmp_path, runs_table(), A8, A0, exploratory="made up")
    text = (tmp_path / "claim_a.md").read_text()
    assert "**Exploratory**: made up" in text and "12 models per alpha" in text
    assert "Interim" not in text  # an exploratory reading is not a part of the plan's study: nothing waits for more
    write_claim_a(tmp_path, runs_table(), A8, A0)
    text = (tmp_path / "claim_a.md").read_text()
    assert "**Interim: 12 of the plan's 20 models per alpha.**" in text  # the pilot plans 20: the verdict waits
    assert "total time spent at T_up 2 s (helps); total time spent at T_up 1 s (helps)" in text
    assert text.count("| **cannot decide** |") == 4 and "| 2 of 12 | 8 of 12 |" in text
    assert (tmp_path / "fig_thrashing.png").read_bytes().startswith(b"\x89PNG")


def test_a_report_of_several_presets_says_how_each_was_trained() -> None:
    """Issue 78: the header of a study of `default` and `alpha_only` said both trained with accident episodes (the
    first preset's text); `alpha_only` trains with none."""
    from dataclasses import replace

    from coopsumo.studies.scenario1.plan import PROFILES
    from coopsumo.studies.scenario1.text import training_text

    both = training_text(replace(PROFILES["full"], presets=("default", "alpha_only")))
    assert "`default`: episodes of 9,000 steps at T_up drawn from 2, 1.5, 1 s, 50% of them with an accident" in both
    assert "`alpha_only`: episodes of 9,000 steps at T_up drawn from 2, 1.5, 1 s, no accident" in both
    assert training_text(replace(PROFILES["default"], presets=("alpha_only",))).endswith("1 s, no accident)")


def test_scenario1_trains_the_learner_protocols_alpha_only_dense_as_the_protocol_did() -> None:
    """Issue 78, step 3: `scenario1 --preset alpha_only_dense` trains the protocol's variant (learners.toml), so the
    pilot's models are the protocol's (one store folder for both); a variant that drives otherwise, or a preset under
    another name (`stks` is `default`), is not a scenario I learner."""
    from dataclasses import replace

    from coopsumo.config import to_dict
    from coopsumo.studies.engine.model_store import model_id
    from coopsumo.studies.protocol.plan import load_profiles, variants
    from coopsumo.studies.protocol.plan import train_config as protocol_train
    from coopsumo.studies.scenario1.plan import PROFILES, learners, train_config
    from coopsumo.studies.scenario1.study import _preset_list
    from coopsumo.studies.scenario1.text import training_text

    known = learners()
    assert known["alpha_only_dense"] == variants()["alpha_only_dense"].learner
    assert "stks" not in known and "alpha_only" in known and "nr10" in known  # nr10: the default before
    profile = load_profiles(variants())[0]["alpha_only_dense"]
    mine = train_config(PROFILES["default"], 0.0, "alpha_only_dense", 104)
    theirs = protocol_train(profile, variants()["alpha_only_dense"], 0.0, 104)
    assert model_id(to_dict(mine)) == model_id(to_dict(theirs))
    assert _preset_list("alpha_only_dense") == ("alpha_only_dense",)
    text = training_text(replace(PROFILES["default"], presets=("alpha_only_dense",)))
    assert "2.67, 2, 1.5, 1.33, 1, 0.89, 0.67 s, no accident" in text
