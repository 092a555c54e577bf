"""The trained model as the unit of replication: the two-level bootstrap (pure) and the model store."""

from __future__ import annotations

import numpy as np

from coopsumo.studies.engine import stats


def _model_dominated() -> np.ndarray:
    """5 models x 5 evaluation seeds: the models differ a lot (their means 3, 2.5, -1.5, 2, -0.5), the seeds of one
    model little (+-0.1)."""
    rng = np.random.default_rng(7)
    means = np.array([3.0, 2.5, -1.5, 2.0, -0.5])
    return means[:, None] + rng.normal(0.0, 0.1, size=(5, 5))


def test_the_two_level_interval_includes_zero_where_the_one_level_one_does_not() -> None:
    table = _model_dominated()
    lo1, hi1 = stats.interval(stats.resampled_means(table.ravel(), 4000, np.random.default_rng(0)), 0.025)  # one level
    mean, lo2, hi2 = stats.hierarchical_bootstrap(table, reps=4000)
    assert lo1 > 0  # the one-level interval claims a difference
    assert lo2 < 0 < hi2  # the models' spread says it cannot be decided
    assert mean == np.mean(table.mean(axis=1))
    assert hi2 - lo2 > 2 * (hi1 - lo1)


def test_the_two_level_interval_narrows_when_models_agree() -> None:
    rng = np.random.default_rng(3)
    agree = 1.0 + rng.normal(0.0, 0.3, size=(5, 5))
    _, lo, hi = stats.hierarchical_bootstrap(agree, reps=2000)
    assert 0 < lo < 1 < hi


def test_one_row_is_the_bootstrap_over_seeds_and_nans_are_dropped() -> None:
    row = np.array([[1.0, 2.0, np.nan, 4.0]])
    mean, lo, hi = stats.hierarchical_bootstrap(row, reps=3000)
    assert mean == 7.0 / 3
    assert 1.0 <= lo < mean < hi <= 4.0
    assert np.isnan(stats.hierarchical_bootstrap(np.full((2, 3), np.nan))[0])
    assert stats.hierarchical_bootstrap(np.array([[1.5]])) == (1.5, 1.5, 1.5)
    # a model whose every value is missing is left out; the others weigh equally whatever their seed count
    mean, _, _ = stats.hierarchical_bootstrap(np.array([[1.0, 1.0, 1.0], [3.0, np.nan, np.nan], [np.nan] * 3]))
    assert mean == 2.0


def test_a_resample_is_one_seeded_call_and_two_levels_draw_the_models_first() -> None:
    rng = np.random.default_rng
    assert (stats.resample(rng(5), 4, 3, 2) == rng(5).integers(0, 4, size=(3, 4, 2))).all()  # one call, per column
    counts = np.array([1, 3, 5])
    models, seeds = stats.resample_two_levels(rng(9), counts, 5, 200)
    assert (models == rng(9).integers(0, 3, size=(200, 3))).all()  # the models drawn first
    assert seeds.shape == (200, 3, 5) and 0 == seeds.min() < seeds.max() == 4  # up to the 5-seed model's last
    assert (seeds < counts[models][:, :, None]).all()  # each drawn model's seeds among its own


def test_the_percentile_interval_of_resampled_means_covers_the_true_mean() -> None:
    assert stats.interval(np.arange(101.0), 0.05) == (5.0, 95.0) and np.isnan(stats.interval(np.zeros(0), 0.05)).all()
    sample = np.random.default_rng(1).normal(3.0, 1.0, size=200)
    means = stats.resampled_means(sample, 2000, np.random.default_rng(2))
    low, high = stats.interval(means, 0.025)
    assert low < 3.0 < high and high - low < 0.6
    assert (stats.resampled_means(sample, 50, np.random.default_rng(2)) == means[:50]).all()  # seeded: repeats


def test_models_needed_grows_with_the_spread() -> None:
    assert stats.models_needed(np.array([1.0])) is None
    few = stats.models_needed(np.array([1.0, 1.2, 0.8]))
    many = stats.models_needed(np.array([3.0, -1.0, 2.0, -0.5]))
    assert few is not None and many is not None and few < many
    assert many >= 5  # more than the models there are


# -- the model store and the committed report, with real trainings and SUMO runs --------------------------------
import hashlib  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from coopsumo.config import to_dict  # noqa: E402
from coopsumo.dqn_config import DQNConfig  # noqa: E402
from coopsumo.studies.engine import model_store  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SMALL = ["-m", "coopsumo", "scenario1", "--quick", "--train-steps", "300", "--steps", "300", "--seeds", "1",
         "--t-up", "2", "--mobil-p", "0", "--alphas", "0", "--workers", "2"]  # fmt: skip
"""a small scenario I: models at alpha 0 only, one demand, one evaluation seed"""


def _study(out: Path | None, *extra: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", model_store.STORE_ENV)}
    return subprocess.run([sys.executable, *SMALL, *extra, *(["--out", str(out)] if out else [])], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600, check=False)  # fmt: skip


def _study_here(out: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str],
                *extra: str) -> tuple[int, str]:  # fmt: skip
    """_study's study by scenario I's main in this process, with _study's environment, for a study the test ran as a
    process before (or a one-line refusal: as a process in tests/test_bad_inputs.py): its exit code and stderr (its
    workers' too)."""
    from coopsumo.studies.scenario1 import study as scenario1

    with monkeypatch.context() as patch:
        patch.delenv("DISPLAY", raising=False)
        patch.delenv(model_store.STORE_ENV, raising=False)
        capfd.readouterr()
        code = scenario1.main([*SMALL[3:], *extra, "--out", str(out)])
        return code, capfd.readouterr().err


def test_scenario_one_takes_the_protocols_models_from_the_store() -> None:
    """The default scenario I trains exactly the learner protocol's models (same identity, so one stored model)."""
    from coopsumo.studies.protocol import plan as protocol_plan
    from coopsumo.studies.scenario1 import plan as scenario1_plan

    for alpha in (0.0, 8.0):
        for seed in scenario1_plan.PROFILES["default"].train_seeds:
            s1 = to_dict(scenario1_plan.train_config(scenario1_plan.PROFILES["default"], alpha, "default", seed))
            stks = protocol_plan.variants()["stks"]  # the default learner
            proto = to_dict(protocol_plan.train_config(protocol_plan.PROFILES["nr10"], stks, alpha, seed))
            assert model_store.model_id(s1) == model_store.model_id(proto)
    base = to_dict(scenario1_plan.train_config(scenario1_plan.PROFILES["default"], 0.0, "default", 100))
    other = to_dict(scenario1_plan.train_config(scenario1_plan.PROFILES["default"], 0.0, "default", 101))
    assert model_store.model_id(base) != model_store.model_id(other)  # a changed setting is another model


@pytest.mark.sumo
def test_a_second_study_takes_stored_models_and_a_tampered_one_is_retrained(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The first study runs as a process; the second, which judges what it left in the store, by scenario I's main in
    this process, and so does the listing (`coopsumo models` as a process: tests/test_extending.py)."""
    from coopsumo.studies.engine import store_listing

    first, second = tmp_path / "first", tmp_path / "second"
    res = _study(first, "--train-seeds", "2")
    assert res.returncode == 0, res.stderr[-2000:]
    assert "0 of 2 models from the model store" in res.stderr
    store = tmp_path / "models"  # beside the studies
    stored = sorted(p for p in store.iterdir() if p.is_dir())
    assert [p.name.split("_")[2] for p in stored] == ["seed100", "seed101"]
    stamps = {p: (p / "model.pt").stat().st_mtime_ns for p in stored}
    # 1. another study asking for the same models trains nothing: its model folders link to the stored ones
    code, err = _study_here(second, monkeypatch, capfd, "--train-seeds", "2")
    assert code == 0, err[-2000:]
    assert "2 of 2 models from the model store" in err and "0 trainings" in err
    assert {(second / "models" / f"alpha0_m{k}").resolve() for k in (100, 101)} == set(stored)
    assert {p: (p / "model.pt").stat().st_mtime_ns for p in stored} == stamps
    runs_first = (first / "runs.csv").read_text()
    assert (second / "runs.csv").read_text() == runs_first.replace(str(first), str(second))
    # 2. a hand-edited config.json: that model is not used but trained again, with one line; the other is kept
    edited = stored[0] / "config.json"
    record = json.loads(edited.read_text())
    record["config"]["dqn"]["lr"] = 0.5
    edited.write_text(json.dumps(record))
    capfd.readouterr()
    code = store_listing.main(["--store", str(store)])
    listing = capfd.readouterr()
    assert code == 0, listing.err
    lines = listing.out.splitlines()
    assert lines[-1] == f"2 models in {store}, 1 usable"
    assert "not this folder's identity" in next(line for line in lines if line.startswith(stored[0].name))
    assert next(line for line in lines if line.startswith(stored[1].name)).rstrip().endswith(" ok")
    code, err = _study_here(second, monkeypatch, capfd, "--train-seeds", "2")
    assert code == 0, err[-2000:]
    lines = [line for line in err.splitlines() if "another configuration than its config.json" in line]
    assert len(lines) == 1 and str(stored[0]) in lines[0], err[-2000:]
    assert (stored[1] / "model.pt").stat().st_mtime_ns == stamps[stored[1]]
    assert json.loads(edited.read_text())["config"]["dqn"]["lr"] == DQNConfig().lr  # retrained as its identity
    assert (second / "runs.csv").read_text() == runs_first.replace(str(first), str(second))  # the same model again


def test_more_models_per_alpha_go_to_their_own_folder() -> None:
    """`make scenario1 TRAIN_SEEDS=10` writes results/scenario1_10models, never over the committed 5-model report;
    the other profiles keep their folders whatever their model count."""
    from dataclasses import replace

    from coopsumo.studies.scenario1.plan import PROFILES
    from coopsumo.studies.scenario1.study import study_out

    default = PROFILES["default"]
    assert study_out(default) == Path("results/scenario1")
    assert study_out(replace(default, train_seeds=tuple(range(100, 110)))) == Path("results/scenario1_10models")
    assert study_out(replace(default, train_seeds=(100, 101, 102))) == Path("results/scenario1_3models")
    assert study_out(replace(PROFILES["quick"], train_seeds=(100,))) == Path("results/scenario1_quick")
    # another learner never writes the default learner's folder, in any profile
    alpha_only = replace(PROFILES["default"], presets=("alpha_only",), train_seeds=tuple(range(100, 110)))
    assert study_out(alpha_only) == Path("results/scenario1_alpha_only_10models")
    assert study_out(replace(PROFILES["default"], presets=("alpha_only",))) == Path("results/scenario1_alpha_only")
    assert study_out(replace(PROFILES["full"], presets=("alpha_only",))) == Path("results/scenario1_full_alpha_only")
    assert study_out(replace(PROFILES["quick"], presets=("default", "paper"))) == Path(
        "results/scenario1_quick_default_paper")  # fmt: skip


def _digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


@pytest.mark.sumo
def test_a_quick_run_leaves_the_committed_report_byte_identical(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """`make scenario1 QUICK=1` (coopsumo scenario1 --quick) writes into results/scenario1_quick; asked to write
    into the default profile's folder, it refuses with one line (scenario I's main in this process: a refusal as a
    process is tests/test_bad_inputs.py's)."""
    committed = tmp_path / "results" / "scenario1"
    shutil.copytree(REPO / "results" / "scenario1", committed, ignore=shutil.ignore_patterns("runs", "models",
                                                                                             "cells", ".*"))
    before = _digests(committed)
    assert "report.md" in before and "plan.json" in before
    res = _study(None, "--train-seeds", "1", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (tmp_path / "results" / "scenario1_quick" / "report.md").is_file()
    assert _digests(committed) == before
    code, err = _study_here(committed, monkeypatch, capfd, "--train-seeds", "1")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "holds the default profile's study" in err and "results/scenario1_quick" in err
    assert _digests(committed) == before
