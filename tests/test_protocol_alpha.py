"""The protocol's alpha response (Profile.alphas, alpha_seeds, alpha_variants; studies/protocol/alpha_response.py):
each alpha variant's models at every alpha of the grid, an alpha-conditioned one trained once a seed, and the
report's tables and figure read over models."""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from coopsumo.studies.protocol.alpha_response import FIGURE, alpha_lines, pairs_lines, response_figure, response_table
from coopsumo.studies.protocol.plan import PROFILES, cell_specs, variants


def test_the_conditioned_profile_drives_each_alpha_variant_at_every_alpha() -> None:
    profile = PROFILES["conditioned"]
    models = [s for s in cell_specs(profile) if s["kind"] == "model"]
    above = [s for s in models if s["alpha"] > 0]
    per = Counter((s["variant"], s["alpha"]) for s in above)
    assert set(per) == {(v, a) for v in ("stks", "c2xs") for a in profile.alphas}
    assert set(per.values()) == {profile.alpha_seeds * len(profile.t_ups)}  # free flow only, every demand
    assert {s["scenario"] for s in above} == {"free"}
    # every model is driven at its cell's alpha; the conditioned network's world stays at alpha 0
    assert all(s["config"]["eval"]["reward"]["alpha"] == s["alpha"] for s in models)
    trainings = {s["train_key"]: s["config"]["train"] for s in models}
    c2xs = {k: t for k, t in trainings.items() if k.endswith("_x2")}
    assert len({str(t) for t in c2xs.values()}) == len(profile.seeds)  # one network a seed for every alpha
    assert {t["sim"]["steps"] for t in c2xs.values()} == {2 * profile.train_steps}  # its steps_factor
    assert {t["sim"]["reward"]["alpha"] for t in c2xs.values()} == {0.0}
    stks = [t for k, t in trainings.items() if k not in c2xs]
    assert len({str(t) for t in stks}) == len(profile.seeds) + len(profile.alphas) * profile.alpha_seeds
    assert {t["sim"]["steps"] for t in stks} == {profile.train_steps}
    assert variants()["c2xs"].learner.alpha_conditioned and not variants()["stks"].learner.alpha_conditioned


def test_a_profile_without_a_grid_measures_alpha_8_of_its_judged_variant() -> None:
    """The committed profiles' alpha response, as before the grid: the judged variant at alpha 8 on alpha_seeds."""
    profile = PROFILES["nr10"]
    above = [s for s in cell_specs(profile) if s["kind"] == "model" and s["alpha"] > 0]
    assert profile.alphas == (8.0,) and profile.alpha_variants == ()
    assert {(s["variant"], s["alpha"]) for s in above} == {("nr10", 8.0)}
    assert len({s["train_key"] for s in above}) == profile.alpha_seeds


def _models(speeds: dict[tuple[str, float], list[float]]) -> pd.DataFrame:
    rows = [{"kind": "model", "scenario": "free", "variant": v, "alpha": a, "seed": 100 + i, "t_up": 1.0,
             "mean_speed_mps": x, "lane_changes_per_vehicle": 1.0 / (1.0 + a) + 0.01 * i}
            for (v, a), xs in speeds.items() for i, x in enumerate(xs)]  # fmt: skip
    return pd.DataFrame(rows)


def test_the_response_reads_each_variant_over_models(tmp_path: Path) -> None:
    profile = replace(PROFILES["conditioned"], alphas=(1.0, 8.0))
    speeds = {(v, a): [20.0 - a * (0.1 if v == "stks" else 0.2) + d for d in (-0.3, 0.0, 0.1, 0.3)]
              for v in ("stks", "c2xs") for a in (0.0, 1.0, 8.0)}  # fmt: skip
    ok = _models(speeds)
    table = response_table(ok[ok["variant"] == "c2xs"], (0.0, 1.0, 8.0))
    assert list(table["models"]) == [4, 4, 4]
    assert np.allclose(table["mean_speed_mps"], [20.05, 19.85, 18.45])  # IQM: the middle two models' mean
    assert (table["mean_speed_mps_low"] <= table["mean_speed_mps"]).all()
    assert (table["mean_speed_mps"] <= table["mean_speed_mps_high"]).all()
    text = "\n".join(alpha_lines(profile, ok))
    assert "How `stks` responds to alpha" in text and "How `c2xs` responds to alpha" in text
    assert "| 1 | 8 | 4 | 18.45 [" in text  # c2xs at alpha 8
    assert "| 1 | 8 | 4 | 19.25 [" in text  # stks at alpha 8
    assert f"![alpha response]({FIGURE})" in text
    assert response_figure(profile, ok, tmp_path / FIGURE) is not None
    assert (tmp_path / FIGURE).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_one_alpha_besides_0_asks_only_whether_alpha_does_something(tmp_path: Path) -> None:
    profile = PROFILES["nr10"]
    ok = _models({("nr10", 0.0): [20.0, 21.0, 22.0], ("nr10", 8.0): [19.0, 20.0, 21.0]})
    lines = alpha_lines(profile, ok)
    assert lines[:4] == ["## Does alpha do something? (free flow, `nr10`, lane changes per vehicle)", "",
                         "| T_up (s) | alpha 0 (models) | alpha 8 (models) |", "|---|---|---|"]  # fmt: skip
    assert lines[4] == "| 1 | 1.010 (3) | 0.121 (3) |"
    assert not any("responds" in line for line in lines)
    assert response_figure(profile, ok, tmp_path / FIGURE) is None and not (tmp_path / FIGURE).exists()
    assert alpha_lines(profile, ok[ok["alpha"] == 0]) == []  # no model above alpha 0: no section


def _paired(gap: dict[int, float], keep_mps: float = 19.0, changes: float = 1.0) -> pd.DataFrame:
    """stks and c2xs models on seeds 100-104 at alphas 0, 1, 8, c2xs `gap[seed]` m/s faster; seed 104 without its
    alpha 8 models (it is left out of the headline); `keep` beside them at keep_mps."""
    speeds = [{"kind": "baseline", "scenario": "free", "variant": "keep", "alpha": 0.0, "seed": None, "t_up": 1.0,
               "mean_speed_mps": keep_mps, "lane_changes_per_vehicle": 0.0}]  # fmt: skip
    for seed, g in gap.items():
        for alpha in (0.0, 1.0, 8.0):
            if seed == 104 and alpha == 8.0:
                continue
            for variant, extra in (("stks", 0.0), ("c2xs", g)):
                speeds.append({"kind": "model", "scenario": "free", "variant": variant, "alpha": alpha, "seed": seed,
                               "t_up": 1.0, "mean_speed_mps": 20.0 - 0.1 * alpha + 0.05 * seed + extra,
                               "lane_changes_per_vehicle": changes})  # fmt: skip
    return pd.DataFrame(speeds)


def test_the_second_alpha_variant_is_paired_with_the_first_by_seed() -> None:
    profile = replace(PROFILES["conditioned"], alphas=(1.0, 8.0))
    slower = "\n".join(pairs_lines(profile, _paired({100: -0.5, 101: -0.4, 102: -0.6, 103: -0.5, 104: 3.0})))
    assert "## `c2xs` against `stks`, paired by training seed" in slower
    found = re.search(r"mean over 4 seeds: (\S+) m/s \[95% CI (\S+), (\S+)\]: decided, `c2xs` slower\.", slower)
    assert found, slower  # seed 104, without alpha 8, left out; the interval within the seeds' own range
    mean, low, high = map(float, found.groups())
    assert mean == -0.5 and -0.6 <= low < mean < high < -0.4
    assert "| 1 | 8 | 4 | -0.50 [" in slower and "| 1 | 0 | 5 | +0.20 [" in slower  # the rows keep every seed
    undecided = "\n".join(pairs_lines(profile, _paired({100: -0.5, 101: 0.5, 102: -0.3, 103: 0.5, 104: 0.0})))
    assert "mean over 4 seeds: +0.05 m/s" in undecided and ": cannot decide (about " in undecided, undecided
    assert pairs_lines(PROFILES["nr10"], _paired({100: 0.0})) == []  # one alpha variant: nothing to pair
    # learners unfit for the question are not read for it
    slow = "\n".join(pairs_lines(profile, _paired({100: -0.5, 101: -0.4}, keep_mps=40.0)))
    unfit = "No verdict (a learner unfit to answer): "
    assert unfit + "`stks` is slower than `keep` at every demand (alpha 0, free flow); `c2xs` is slower" in slow
    assert "Headline" not in slow
    calm = "\n".join(pairs_lines(profile, _paired({100: -0.5, 101: -0.4}, changes=0.0)))
    assert unfit + "`stks` makes no lane change at alpha 0; `c2xs` makes no lane change" in calm


def test_the_header_names_a_learner_trained_longer() -> None:
    """c2xs trains twice the profile's steps (its steps_factor): the report's first line says so; a profile without
    such a learner reads as before."""
    from coopsumo.studies.protocol.report import _header_lines

    learners = {n: {"text": v.text, "weights": v.weights} for n, v in variants().items()}
    meta = {"cells": 1, "cells_run": 1, "wall_seconds": 1.0, "workers": 2, "cell_cpu_seconds_sum": 3600.0,
            "learners": learners}
    assert "each learner trained 90,000 steps, `c2xs` 180,000 (in free flow" in _header_lines(PROFILES["conditioned"],
                                                                                              meta)[2]
    assert "each learner trained 90,000 steps (in free flow" in _header_lines(PROFILES["nr10"], meta)[2]


def test_a_profile_with_an_analysis_plan_quotes_its_commit(tmp_path: Path) -> None:
    """The conditioned profile's report quotes the commit of the plan fixed before its models were driven (the
    research rule: the report quotes the plan's commit), a commit of this repository; a profile without a plan says
    nothing of one; a profile file's plan must be a commit's hash, refused in one line naming the field."""
    import json
    import subprocess

    from coopsumo.errors import ConfigError
    from coopsumo.studies.protocol.plan import own_profiles
    from coopsumo.studies.protocol.report import plan_line

    root = Path(__file__).resolve().parents[1]
    conditioned = PROFILES["conditioned"]
    assert conditioned.plan and not PROFILES["nr10"].plan and plan_line(PROFILES["nr10"]) == []
    (line,) = plan_line(conditioned)
    assert f"commit `{conditioned.plan}`" in line
    assert line in (root / "results" / "learner_protocol_conditioned" / "report.md").read_text().splitlines()
    if (root / ".git").exists():
        found = subprocess.run(["git", "cat-file", "-e", f"{conditioned.plan}^{{commit}}"], cwd=root, check=False)
        assert found.returncode == 0, f"{conditioned.plan} is not a commit of this repository"
    path = tmp_path / "mine.toml"
    for plan, ok in (("x; rm -rf /", False), ("C68A4EE", False), ("c68a4", False), ("c68a4ee", True)):
        path.write_text(f'[profiles.mine]\nvariants = ["stks"]\nplan = {json.dumps(plan)}\n')
        if ok:
            assert own_profiles(path)[0]["mine"].plan == plan
        else:
            with pytest.raises(ConfigError, match=r"\[profiles.mine\] plan must be a commit's hash \(7 to 40 hex"):
                own_profiles(path)
