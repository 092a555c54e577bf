"""Issue 82, fifth probe, G4: a record that is a named pipe (a FIFO) hung the command reading it, without a line: a run
folder's marker or an ancestor's, a study's marker, a merge part's sweep.json, a store model's config.json. Every
record is now read through files.open_regular, which refuses a named pipe, a socket, a device or a folder before it
reads a byte ("... is not a regular file but a named pipe"); each reader then does what it does with an unreadable
record: a refusal in one line, exit 2, or the record taken as damaged and redone. Every test here runs under a
deadline: a read that waits on a pipe fails it instead of hanging the suite."""

from __future__ import annotations

import json
import os
import signal
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import assert_refused_in_one_line, main_here

from coopsumo import files
from coopsumo.errors import NotRegularFileError
from coopsumo.run_dirs import RUN_MARKER, mark_run_dir

PIPE = "is not a regular file but a named pipe"


@pytest.fixture(autouse=True)
def deadline() -> Iterator[None]:
    """SIGALRM after 30 s raises TimeoutError wherever the test waits (a read of a pipe that nobody writes)."""

    def expire(signum: int, frame: Any) -> None:
        raise TimeoutError("waited on a named pipe")

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, 30.0)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)


def _entry(kind: str, path: Path) -> Path:
    """An entry of `kind` at path that is not a regular file: a named pipe, a folder, a socket, a link to a device."""
    if kind == "pipe":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        sock.close()
    else:
        path.symlink_to("/dev/zero")  # read to its end, it would never end
    return path


READERS: dict[str, Callable[[Path], Any]] = {"open_regular": files.open_regular, "read_bytes": files.read_bytes,
                                             "read_text": files.read_text, "read_json": files.read_json,
                                             "read_csv": files.read_csv, "file_sha256": files.file_sha256}  # fmt: skip


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize(("kind", "words"), [("pipe", "a named pipe"), ("folder", "a folder"), ("socket", "a socket"),
                                             ("device", "a device")])  # fmt: skip
def test_every_record_reader_refuses_what_is_not_a_regular_file(reader: str, kind: str, words: str,
                                                                 tmp_path: Path) -> None:  # fmt: skip
    path = _entry(kind, tmp_path / "s")  # short: a socket's path has at most 107 bytes
    with pytest.raises(NotRegularFileError) as refused:
        READERS[reader](path)
    assert str(refused.value) == f"{path} is not a regular file but {words}"
    assert refused.value.strerror == f"not a regular file but {words}" and refused.value.filename == str(path)
    assert files.read_json_object(path) is None  # an unreadable record, as one that is not JSON


def test_a_pipe_put_in_place_after_the_look_is_refused_on_the_open_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """The look before the open (os.stat) and the open race: the open never waits (O_NONBLOCK) and the open file's
    own kind (fstat) decides."""
    fifo = _entry("pipe", tmp_path / "record.json")
    monkeypatch.setattr(files, "not_regular", lambda path: None)  # as if the pipe came after the look
    with pytest.raises(NotRegularFileError, match=PIPE):
        files.read_json(fifo)
    regular = tmp_path / "ok.json"
    regular.write_text('{"a": 1}\r\n')
    assert files.read_json(regular) == {"a": 1} and files.read_text(regular) == '{"a": 1}\n'


def test_run_cli_says_it_in_one_line_with_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from coopsumo.runio import run_cli

    fifo = _entry("pipe", tmp_path / "record.json")
    assert run_cli("coopsumo x", lambda: files.read_json(fifo)) == 2
    assert capsys.readouterr().err == f"coopsumo x: error: {fifo} {PIPE}\n"


def test_a_run_folder_whose_marker_is_a_pipe_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The probe's r_marker_fifo: `simulate --out sim` over a folder whose marker is a named pipe hung."""
    from coopsumo.simulate import main

    out = tmp_path / "sim"
    out.mkdir()
    _entry("pipe", out / RUN_MARKER)
    code, _, err = main_here(main, ["--steps", "200", "--out", str(out), "--quiet"], capsys)
    assert_refused_in_one_line(code, err, tmp_path / "nothing", f"has a {RUN_MARKER} that cannot be read (not a "
                               "regular file but a named pipe) and is left alone")  # fmt: skip
    assert sorted(p.name for p in out.iterdir()) == [RUN_MARKER]


def test_a_marker_that_is_a_pipe_is_not_waited_on(tmp_path: Path) -> None:
    """The probe's r_marker_fifo_ancestor and r_s2_marker_fifo: the check of every ancestor's marker (owners) and a
    study root's marker read it as they read an unreadable one, without waiting on it: a study root's claims no study
    (it is written anew); an ancestor's claims its folder as a damaged marker does, so nothing is written below it
    (issue 82, probe 8, J2: `simulate --out s2/sim` below a damaged marker was written)."""
    from coopsumo.owners import owned_problem
    from coopsumo.run_dirs import held_study
    from coopsumo.run_markers import marker_kind

    (tmp_path / "a").mkdir()
    _entry("pipe", tmp_path / "a" / RUN_MARKER)
    assert marker_kind(tmp_path / "a") is None and held_study(tmp_path / "a") is None
    problem = owned_problem(tmp_path / "a" / "b" / "sim", "--out a/b/sim")
    assert problem is not None and f"lies inside {tmp_path / 'a'}, whose .coopsumo-run.json cannot be read" in problem


def _store_model(store: Path) -> tuple[Path, dict[str, Any]]:
    """A finished training's folder in `store` (a model.pt of bytes), and its configuration."""
    from coopsumo.config import SimConfig, TrainConfig, to_dict
    from coopsumo.studies.engine.model_store import model_id

    config = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=100, policy="dqn"), eval_steps=0))
    folder = store / model_id(config)
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"config": config}))
    (folder / "train_summary.json").write_text(json.dumps({"steps": 300}))
    (folder / "model.pt").write_bytes(b"weights")
    mark_run_dir(folder, "train")
    return folder, config


def test_a_store_models_config_json_that_is_a_pipe_is_listed_and_trained_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's r_models_cfg_fifo: `coopsumo models` hung; a study's look at the model (finished_training) too."""
    from coopsumo.studies.engine import store_listing
    from coopsumo.studies.engine.trainings import finished_training

    folder, config = _store_model(tmp_path / "store")
    (folder / "config.json").unlink()
    _entry("pipe", folder / "config.json")
    assert store_listing.main(["--store", str(tmp_path / "store")]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith(folder.name))
    assert "no readable config.json (not a regular file but a named pipe)" in row, row
    assert finished_training(folder, config) is None
    assert capsys.readouterr().err == (f"coopsumo: {folder} holds a model.pt but its config.json is missing or "
                                       "unreadable (not a regular file but a named pipe); training it again\n")


def test_a_merge_part_whose_sweep_json_is_a_pipe_is_refused(tmp_path: Path) -> None:
    """The probe's r_merge_sweep_fifo: `scenario2 --merge part` hung."""
    from coopsumo.errors import UsageError
    from coopsumo.studies.scenario2.redraw import _read_part

    part = tmp_path / "part"
    part.mkdir()
    _entry("pipe", part / "sweep.json")
    with pytest.raises(UsageError, match=f"--merge: {part} is not a finished scenario2 sweep "
                                         f"\\({part / 'sweep.json'} {PIPE}\\)"):  # fmt: skip
        _read_part(part)


@pytest.mark.parametrize("study", ["scenario2", "protocol"])
def test_a_profile_file_that_is_a_pipe_says_so(study: str, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's borderline r_profile_fifo: `--profile FIFO.toml` was refused as "no file"."""
    import importlib

    from coopsumo.errors import ConfigError
    from coopsumo.studies.engine.catalogue import read_toml

    fifo = _entry("pipe", tmp_path / "p.toml")
    main = importlib.import_module(f"coopsumo.studies.{study}.study").main
    code, _, err = main_here(main, ["--profile", str(fifo), "--out", str(tmp_path / "out"), "--quiet"], capsys)
    assert_refused_in_one_line(code, err, tmp_path / "out", f"--profile {fifo}: {fifo} {PIPE}")
    with pytest.raises(ConfigError, match=f"{fifo}: cannot read it \\(not a regular file but a named pipe\\)"):
        read_toml(fifo)


def test_a_table_or_study_record_that_is_a_pipe_is_named(tmp_path: Path) -> None:
    """CSV records (record_schemas.Table.read, `history`'s study.json and stats.csv) and a run folder's SUMO files."""
    from coopsumo.record_schemas import PROTOCOL_STATS, RecordError
    from coopsumo.studies.engine.run_checks import detectors_problem, fcd_problem, tripinfo_problem
    from coopsumo.studies.protocol.history import records

    fifo = _entry("pipe", tmp_path / "stats.csv")
    with pytest.raises(RecordError, match=f"{fifo} cannot be read as a table \\(not a regular file but a named pipe"):
        PROTOCOL_STATS.read(fifo)
    _entry("pipe", tmp_path / "study.json")
    with pytest.raises(RecordError, match="study.json cannot be read as JSON \\(not a regular file but a named pipe"):
        records(tmp_path)
    unreadable = "(not a regular file but a named pipe)"
    assert detectors_problem(fifo, {}, 10.0) == f"has an unreadable detectors.xml {unreadable}"
    assert fcd_problem(fifo, 10.0, 1.0, 0.1) == f"has an unreadable fcd.xml {unreadable}"
    assert tripinfo_problem(fifo, {}) == f"has an unreadable tripinfo.xml {unreadable}"


def test_a_training_log_or_network_that_is_a_pipe_is_named(tmp_path: Path) -> None:
    """`train --resume` reads the log it keeps (training_logs.log_problem); the networks folder's cached network."""
    from coopsumo.agents.training_logs import log_problem, validation_problem
    from coopsumo.config import RoadConfig
    from coopsumo.sim.network import net_problem

    fifo = _entry("pipe", tmp_path / "train_log.csv")
    assert log_problem(fifo, 10) == "cannot be read (not a regular file but a named pipe)"
    assert validation_problem(fifo) == "cannot be read (not a regular file but a named pipe)"
    assert net_problem(fifo, RoadConfig()) == "unreadable: not a regular file but a named pipe"
