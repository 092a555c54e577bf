"""Issue 82, probe 4 (F8-F12, F20-F22): records read back edited in ways that were a traceback or trusted (JSON nested
deeply, a profile not UTF-8, numbers too large for a float, a detectors.xml count `6.0`, a checkpoint's log window, a
store model's `sim.seed: true`), and arguments refused only after the runs (`accident-seeds ROOT ROOT`, since
retired; `bench --model` of random bytes)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from coopsumo.agents import train_cli as train
from coopsumo.files import loads_json, read_json_object
from coopsumo.run_dirs import RUN_MARKER
from coopsumo.studies.engine.records import cell_path, reusable_keys

DEEP = "[" * 200_000  # json's decoder raises RecursionError for it
NESTED = "[" * 100 + "]" * 100  # decoded, yet deeper than any record: later code walking it would recurse


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under folder with its sha256."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


def one_line(capsys: pytest.CaptureFixture[str], *fragments: str) -> str:
    """The one line on stderr, which names every fragment; no traceback."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and all(f in lines[0] for f in fragments), err
    return lines[0]


@pytest.mark.parametrize("text", [DEEP, NESTED])
def test_json_nested_deeply_is_not_json(text: str, tmp_path: Path) -> None:
    """F8: the shared reader takes deep nesting for text that is not JSON (a ValueError), not a RecursionError."""
    with pytest.raises(ValueError, match="nested deeper"):
        loads_json(text)
    path = tmp_path / "record.json"
    path.write_text(text)
    assert read_json_object(path) is None
    assert loads_json('{"a": [[{"b": 1}]]}') == {"a": [[{"b": 1}]]}


def test_a_deeply_nested_marker_is_damaged(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """F8: a training folder's marker nested 200,000 deep was a RecursionError traceback on `train --resume`."""
    out = tmp_path / "train"
    out.mkdir()
    (out / "config.json").write_text("{}\n")
    (out / "checkpoint.pt").write_bytes(b"weights")
    (out / RUN_MARKER).write_text(DEEP)
    before = snapshot(tmp_path)
    assert train.main(["--resume", "--quiet", "--out", str(out)]) == 2
    one_line(capsys, str(out), RUN_MARKER, "is not readable JSON (damaged)", "left alone")
    assert snapshot(tmp_path) == before


def test_a_deeply_nested_cell_record_is_rerun(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """F8: a study's cell record nested deeply is unreadable: rerun with one line, like any record not JSON."""
    spec = {"key": "c1", "config": {"steps": 10}}
    path = cell_path(tmp_path, "c1")
    path.parent.mkdir(parents=True)
    path.write_text(DEEP)
    assert reusable_keys(tmp_path, [spec], "scenario2", ["mean_speed_mps"]) == set()
    one_line(capsys, "cell c1", str(path), "unreadable (ValueError); rerunning it")


def test_a_deeply_nested_study_record_is_named(tmp_path: Path) -> None:
    """F8: `history` reading a protocol study's study.json nested deeply: RecordError naming the file."""
    from coopsumo.record_schemas import RecordError
    from coopsumo.studies.protocol.history import records

    (tmp_path / "study.json").write_text(json.dumps({"a": 1})[:-1] + ', "b": ' + DEEP)
    with pytest.raises(RecordError, match="study.json cannot be read as JSON"):
        records(tmp_path)


@pytest.mark.parametrize(("text", "words"), [
    (b'[profiles.mine]\nhelp = "x\xff"\nlanes = [2]\n', "not TOML (not UTF-8: byte 0xff"),
    (b"[profiles.mine]\nlanes = " + b"[" * 50_000 + b"]" * 50_000 + b"\n", "not TOML (nested deeper"),
    (b"[profiles.mine]\nlanes = " + b"[" * 100 + b"]" * 100 + b"\n", "not TOML (nested deeper"),
    (b"[profiles.mine]\nlanes = [" + b"9" * 5000 + b"]\n", "not TOML (Exceeds the limit"),  # fifth probe, G7
], ids=["not_utf8", "recursion", "nested", "digits"])  # fmt: skip
@pytest.mark.parametrize("study", ["scenario2", "protocol"])
def test_a_profile_file_not_utf8_or_nested_deeply_is_not_toml(
        study: str, text: bytes, words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """F9: `--profile a.toml` holding a byte that is not UTF-8, or arrays nested 50,000 deep, was a
    UnicodeDecodeError or RecursionError traceback: one line naming the file, exit 2, nothing written."""
    import importlib

    main = importlib.import_module(f"coopsumo.studies.{study}.study").main
    path = tmp_path / "a.toml"
    path.write_bytes(text)
    assert main(["--profile", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert one_line(capsys, f"{study}: error: {path}: {words}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.toml"]


BIG = int("9" * 400)  # no float holds it: float(BIG) is an OverflowError
CUT = "9" * 37 + "..."  # how a refusal shows it


def test_a_number_too_large_for_a_float_is_out_of_limits_in_every_record_check() -> None:
    """F10: a 400-digit integer was an OverflowError traceback wherever a check converted it with float() or asked
    math.isfinite: record_schemas' rules, the summary checks of the studies, the learner's limits and types."""
    from coopsumo.dqn_config import DQNConfig
    from coopsumo.record_schemas import RUN_SUMMARY
    from coopsumo.studies.engine.records import implausible, record_problem, training_problem
    from coopsumo.validation import limits_problem, type_problem

    speed, updates = RUN_SUMMARY.problem({"mean_speed_mps": BIG}), RUN_SUMMARY.problem({"updates": BIG})
    assert speed == f"field mean_speed_mps must be a finite number >= 0 and <= 70 (m/s), got {CUT}"
    assert updates == f"field updates must be an integer >= 0 (finite as a float), got {CUT}"
    assert CUT in str(implausible({"departed": BIG, "arrived": 3}))
    assert "departed" in str(record_problem({"status": "ok", "summary": {"departed": BIG}}, ["departed"]))
    summary = {"mean_speed_mps": 1.0, "lane_changes": 0, "collisions": 0, "updates": BIG, "wall_seconds": 1.0,
               "steps_per_second": 1.0, "departed": 1, "steps": 10}  # fmt: skip
    assert "updates" in str(training_problem(summary))
    learner = DQNConfig()
    object.__setattr__(learner, "lr", BIG)
    assert type_problem(learner) == f"lr must be a finite number, got {CUT}"
    lr = limits_problem(learner, {"lr": (0.0, 1.0, True, False)})
    assert lr == f"lr must be a finite number > 0 and <= 1, got {CUT}"
    object.__setattr__(learner, "batch_size", BIG)
    batch = limits_problem(learner, {"batch_size": (1, 10, False, False)})
    assert batch == f"batch_size must be an integer from 1 to 10, got {CUT}"


def test_a_table_or_drive_setting_too_large_for_a_float_is_named() -> None:
    """F10: a merge part's runs.csv cell of 400 digits (pandas' to_numeric overflowed) and a protocol study's drive
    setting of 400 digits (history) are refused in words."""
    from coopsumo.studies.protocol.history import drive_problem
    from coopsumo.studies.scenario2.redraw import _no_number

    assert _no_number("9" * 400) and _no_number("x") and not _no_number("12.5")
    assert "which no policy takes" in str(drive_problem({"change_margin": BIG}))


@pytest.mark.parametrize("study", ["scenario2", "protocol"])
def test_a_profile_number_too_large_for_a_float_is_refused(study: str, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """F10: `alphas = [999...]` in a profile of one's own: one line naming the file and the field, exit 2."""
    import importlib

    main = importlib.import_module(f"coopsumo.studies.{study}.study").main
    path = tmp_path / "p.toml"
    words = 'help = "x"\n' if study == "scenario2" else 'variants = ["nr10"]\n'  # a protocol profile names some
    path.write_text(f"[profiles.mine]\n{words}alphas = [{BIG}]\n")
    assert main(["--profile", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    one_line(capsys, f"{path}: [profiles.mine] alphas must be a finite number, got {CUT}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.toml"]


@pytest.mark.parametrize("count", ["6.0", "6e0", " 6"])
def test_a_loop_count_not_written_in_digits_is_not_trusted(count: str, tmp_path: Path) -> None:
    """F11: nVehContrib="6.0" passed the checks (a whole float) and then read_detectors' int() was a ValueError
    traceback; the run is redone with one line naming the field, as for a count of -30 or 0x18."""
    from coopsumo.config import SimConfig, to_dict
    from coopsumo.report.analysis import read_detectors
    from coopsumo.studies.engine.run_checks import detectors_problem

    path = tmp_path / "detectors.xml"
    row = ('<interval begin="0.00" end="60.00" id="e1_x100_l0" nVehContrib="{}" flow="360.00" occupancy="5.00" '
           'speed="20.00"/>\n')  # fmt: skip
    path.write_text("<detector>\n" + row.format("6") + "</detector>\n")
    cfg = to_dict(SimConfig(steps=600))
    assert detectors_problem(path, cfg, 60.0) is None and read_detectors(path)["n_veh"].tolist() == [6]
    path.write_text("<detector>\n" + row.format(count) + "</detector>\n")
    problem = str(detectors_problem(path, cfg, 60.0))
    assert f"field nVehContrib must be written as a whole number, got {count!r}" in problem, problem


def test_a_stored_model_whose_seed_is_true_is_trained_again(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """F20: `sim.seed: true` in a store model's config.json: `coopsumo models` called it not usable, yet a study
    reused it (true == 1 passed the identity check). Both now ask record_schemas.STORE_CONFIG: trained again, one
    line naming the field."""
    from coopsumo.config import SimConfig, TrainConfig, to_dict
    from coopsumo.run_dirs import mark_run_dir
    from coopsumo.studies.engine import model_store, store_listing
    from coopsumo.studies.engine.trainings import finished_training

    config = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=1, policy="dqn"), eval_steps=0))
    folder = tmp_path / model_store.model_id(config)
    folder.mkdir()
    edited = json.loads(json.dumps(config))
    edited["sim"]["seed"] = True
    (folder / "config.json").write_text(json.dumps({"config": edited}))
    (folder / "train_summary.json").write_text(json.dumps({"steps": 300}))
    (folder / "model.pt").write_bytes(b"weights")
    mark_run_dir(folder, "train")
    assert finished_training(folder, config, quiet=True) is None and capsys.readouterr().err == ""
    assert finished_training(folder, config) is None
    one_line(capsys, f"coopsumo: {folder} holds a model.pt but its config.json field config.sim.seed must be an "
             "integer, got True; training it again")  # fmt: skip
    assert store_listing.listing(tmp_path)[0]["state"] == ("not usable: config.json field config.sim.seed must be an "
                                                        "integer, got True")  # fmt: skip


def test_bench_refuses_a_model_file_of_random_bytes_before_its_runs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """F22: `bench --model m.pt` took any existing file and ran its trainings (minutes) before reading it; now it is
    read first, as `--policy dqn:` reads it: one line, exit 2, nothing run."""
    from coopsumo.bench import figures as bench

    def no_run(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("bench ran before refusing the model file")

    monkeypatch.setattr(bench, "world_lines", no_run)
    monkeypatch.setattr(bench, "learner_lines", no_run)
    path = tmp_path / "m.pt"
    path.write_bytes(bytes(range(256)) * 12)
    with pytest.raises(SystemExit) as end:
        bench.main(["--quick", "--model", str(path)])
    assert end.value.code == 2
    err = capsys.readouterr().err
    assert f"coopsumo bench: error: --model: cannot read model file {path}" in err and "Traceback" not in err, err
