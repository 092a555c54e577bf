"""Issue 25, part 3: output paths that SUMO or the file system cannot take are refused before anything is written,
in one line with exit code 2, by every command: a comma (SUMO splits its file lists at commas; ':' is in
test_bad_inputs), a name or path too long for the file system, a loop of symbolic links, a file where a folder
must be, a deleted working folder, non-ASCII characters under an ASCII locale (LC_ALL=C)."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from coopsumo.paths import NAME_ROOM, PATH_ROOM, out_path_problem

REPO = Path(__file__).resolve().parent.parent
COMMANDS = ("simulate", "train", "scenario1", "scenario2", "protocol")
COMMAND_MODULES = {"simulate": "coopsumo.simulate", "train": "coopsumo.train",
                   "scenario1": "coopsumo.studies.scenario1.study", "scenario2": "coopsumo.studies.scenario2.study",
                   "protocol": "coopsumo.studies.protocol.study"}  # fmt: skip
NAME_MAX = os.pathconf("/tmp", "PC_NAME_MAX")
PATH_MAX = os.pathconf("/tmp", "PC_PATH_MAX")


def _comma(tmp: Path) -> Path:
    return tmp / "run,1"


def _long_name(tmp: Path) -> Path:
    return tmp / ("x" * (NAME_MAX - NAME_ROOM + 1))  # the file system takes it, the run's partial folder would not


def _long_path(tmp: Path) -> Path:
    depth = (PATH_MAX - PATH_ROOM) // 200 + 1
    return tmp.joinpath(*["y" * 199] * depth)


def _loop(tmp: Path) -> Path:
    (tmp / "loop_a").symlink_to(tmp / "loop_b")
    (tmp / "loop_b").symlink_to(tmp / "loop_a")
    return tmp / "loop_a" / "run"


def _under_a_file(tmp: Path) -> Path:
    (tmp / "a_file").write_text("not a folder\n")
    return tmp / "a_file" / "run"


CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "comma": (_comma, "without ','"),
    "long name": (_long_name, f"at most {NAME_MAX - NAME_ROOM} are allowed"),
    "long path": (_long_path, f"at most {PATH_MAX - PATH_ROOM} are allowed"),
    "symlink loop": (_loop, "loop of symbolic links"),
    "under a file": (_under_a_file, "a_file is a file, not a folder"),
    "a leading ~ (SUMO's home folder; probe 9)": (lambda tmp: Path("~") / "t", "'~/t' starts with '~', which SUMO"),
    "an environment variable (SUMO's; probe 9)": (lambda tmp: tmp / "d${XV}", "without '${' (SUMO reads ${NAME}"),
}


def snapshot(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.iterdir())


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("command", COMMANDS)
def test_an_output_path_sumo_or_the_file_system_cannot_take_is_refused(
    command: str, case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    make, fragment = CASES[case]
    out = make(tmp_path)
    before = snapshot(tmp_path)
    main = importlib.import_module(COMMAND_MODULES[command]).main
    with pytest.raises(SystemExit) as stop:  # argparse's type= check of --out
        main(["--out", str(out)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and len(lines) == 1, lines
    assert "--out" in lines[0] and fragment in lines[0] and "Traceback" not in lines[0], lines[0]
    assert snapshot(tmp_path) == before  # nothing written


def test_out_path_problem_accepts_ordinary_paths(tmp_path: Path) -> None:
    for ok in ("run", "a b/run", "a;b", "é/run", "x" * (NAME_MAX - NAME_ROOM), "a~b/run", "~/run", "a$b/run"):
        assert out_path_problem(tmp_path / ok) is None, ok
    (tmp_path / "link").symlink_to(tmp_path / "target")  # a link to a folder yet to be made is fine
    assert out_path_problem(tmp_path / "link" / "run") is None
    (tmp_path / "odd,place").mkdir()
    (tmp_path / "plain").symlink_to(tmp_path / "odd,place")
    problem = out_path_problem(tmp_path / "plain" / "run")  # SUMO is given the resolved path
    assert problem is not None and "odd,place" in problem


def _in_deleted_folder(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """`python -m coopsumo.<args>` started in a folder that is deleted just before."""
    gone = tmp_path / "gone"
    gone.mkdir()
    script = f'cd "{gone}" && rmdir "{gone}" && exec "$0" "$@"'
    return subprocess.run(["bash", "-c", script, sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=120, check=False)  # fmt: skip


@pytest.mark.parametrize("args", [
    ["coopsumo.simulate", "--steps", "20", "--quiet", "--out", "run"],
    ["coopsumo.simulate", "--steps", "20", "--quiet", "--out", "ABS"],
    ["coopsumo.train", "--steps", "20", "--eval-steps", "0", "--quiet"],  # the default --out, relative
    ["coopsumo.train", "--steps", "20", "--eval-steps", "0", "--quiet", "--out", "ABS"],
    ["coopsumo", "scenario2", "--profile", "tiny", "--quiet"],  # the default --out, relative
    ["coopsumo", "scenario1", "--quick", "--out", "ABS"],
    ["coopsumo.bench", "--quick"],
], ids=["simulate", "simulate-absolute", "train", "train-absolute", "scenario2", "scenario1-absolute",
        "bench"])  # fmt: skip
def test_a_deleted_working_folder_is_one_line(args: list[str], tmp_path: Path) -> None:
    """Before: a traceback (Path.absolute), or Intel oneMKL's fatal error importing torch (train), or workers that
    could not start. Now every command refuses to run there, an absolute --out too."""
    res = _in_deleted_folder([str(tmp_path / "kept") if a == "ABS" else a for a in args], tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert "current folder no longer exists" in lines[0] and "error" in lines[0], lines[0]
    assert snapshot(tmp_path) == []


def test_a_working_folder_deleted_while_a_command_runs_is_one_line_naming_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 18, O2: the working folder deleted while scenario2, scenario1 or train ran ended in "error: No
    such file or directory", naming nothing, exit 2; now a line saying what happened, exit 1 (not a usage error)."""
    from coopsumo.runio import run_cli

    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)

    def body() -> int:
        here.rmdir()
        Path("run").resolve()  # what a command does with a relative path: os.getcwd() fails, naming no file
        return 0

    assert run_cli("scenario2", body) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("scenario2: error: the current folder was deleted while the command "
                                               "ran (") and "change to an existing folder" in err[0], err


def _with_locale(lc_all: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("LC_") and k != "LANG"}
    return {**env, "LC_ALL": lc_all, "PYTHONPATH": os.pathsep.join(sys.path)}


@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_non_ascii_out_under_an_ascii_locale_is_one_line(command: str, tmp_path: Path) -> None:
    """Before: SUMO could not open the run's files ('The route file ... is not accessible'), a traceback."""
    out = tmp_path / "über"
    args = ["--steps", "20", "--quiet", "--out", str(out)] + (["--eval-steps", "0"] if command == "train" else [])
    res = subprocess.run([sys.executable, "-m", f"coopsumo.{command}", *args], capture_output=True,
                         env=_with_locale("C"), timeout=120, check=False)  # fmt: skip
    err = res.stderr.decode("utf-8", "replace")
    lines = err.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and "Traceback" not in err, err[-2000:]
    assert "non-ASCII" in lines[0] and "LC_ALL=C.UTF-8" in lines[0]
    assert snapshot(tmp_path) == []


@pytest.mark.sumo
def test_a_non_ascii_out_under_a_utf8_locale_runs(tmp_path: Path) -> None:
    out = tmp_path / "über"
    res = subprocess.run([sys.executable, "-m", "coopsumo.simulate", "--steps", "20", "--quiet", "--out", str(out)],
                         capture_output=True, env=_with_locale("C.UTF-8"), timeout=120, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert (out / "summary.json").is_file()


@pytest.mark.sumo
@pytest.mark.parametrize("damage", ["empty", "cut short", "garbage", "a lane removed", "another lane count",
                                    "another length", "another speed limit", "a lane forbids cars",
                                    "no lane changes", "no seal"])
def test_a_damaged_cached_network_is_built_again_once_with_a_line(
    damage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A cached .net.xml that is empty, cut short, not XML, missing a lane or another road's (lanes, length, speed
    limit) is rebuilt by netconvert with one line naming it; an intact one is used as it is, without a line. Issue 82
    (e10f): lanes of 500 m were trusted, and SUMO failed on the loops beyond their end."""
    from coopsumo.config import RoadConfig
    from coopsumo.sim.network import build_net, net_problem

    road = RoadConfig(lanes=3)
    path = build_net(road, tmp_path)
    good = path.read_text()
    assert net_problem(path, road) is None and build_net(road, tmp_path) == path and capsys.readouterr().err == ""
    spoiled = {"empty": "", "cut short": good[: len(good) // 2], "garbage": "\x00\x01 not xml at all",
               "a lane removed": good.replace('<lane id="road_2"', '<lane id="road_x"'),
               "another lane count": build_net(RoadConfig(lanes=2), tmp_path / "two").read_text(),
               "another length": good.replace('length="2000.00"', 'length="500.00"'),
               "another speed limit": good.replace('speed="33.34"', 'speed="13.89"'),
               # probe 18, TB1 and TR2: a traceback in SUMO, and other results without a line
               "a lane forbids cars": good.replace('<lane id="road_1" index="1"',
                                                   '<lane id="road_1" index="1" disallow="passenger"'),
               "no lane changes": good.replace(' index="0"', ' index="0" changeLeft="bus" changeRight="bus"'),
               "no seal": good[: good.rindex("<!-- coopsumo sha256 ")]}[damage]  # an older coopsumo's
    assert spoiled != good
    path.write_text(spoiled)
    assert net_problem(path, road) is not None
    assert build_net(road, tmp_path) == path
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "building it again" in err[0], err
    body = path.read_text()  # netconvert's header comment carries the time it ran
    assert net_problem(path, road) is None and body[body.index("<net "):] == good[good.index("<net "):]


def test_a_folder_in_place_of_the_network_file_is_one_line_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82 (e10h): a user's folder where the .net.xml goes was reported by the temporary file it was to replace
    (and that file left in the networks folder); now one line naming the folder, exit 2, the folder kept."""
    from conftest import main_here

    from coopsumo import cli
    from coopsumo.config import RoadConfig
    from coopsumo.paths import NETS_ENV
    from coopsumo.sim.network import net_name

    nets, out = tmp_path / "nets", tmp_path / "out"
    folder = nets / f"{net_name(RoadConfig(lanes=3))}.net.xml"
    folder.mkdir(parents=True)
    (folder / "mine.txt").write_text("a user's file")
    monkeypatch.setenv(NETS_ENV, "")  # so that teardown restores it: cli.main below sets it
    code, _, err = main_here(cli.main, ["--nets-dir", str(nets), "simulate", "--steps", "5", "--quiet",
                                        "--out", str(out)], capsys)  # fmt: skip
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].endswith(str(folder)) and "is a folder" in lines[0], err
    assert "Traceback" not in err and not out.exists()
    assert sorted(p.name for p in nets.glob("*.net.xml")) == [folder.name]  # no temporary file left
    assert (folder / "mine.txt").read_text() == "a user's file"


@pytest.mark.sumo
def test_a_link_in_the_networks_folder_is_replaced_never_written_through(tmp_path: Path) -> None:
    """Issue 82, fourth probe (F4 of report F5): a link named like the road's .nod.xml (or .edg.xml) in the networks
    folder, leading to a user's file, had the nodes written into that file. The network's input files are made new
    and renamed over the name: the link is replaced, the user's file keeps its bytes, no temporary file is left."""
    from coopsumo.config import RoadConfig
    from coopsumo.sim.network import build_net, net_name, net_problem

    road, nets, user = RoadConfig(lanes=2), tmp_path / "nets", tmp_path / "user"
    nets.mkdir()
    user.mkdir()
    stem = net_name(road)
    for suffix in ("nod", "edg"):
        (user / f"{suffix}.xml").write_text("<my own file/>\n")
        (nets / f"{stem}.{suffix}.xml").symlink_to(user / f"{suffix}.xml")
    path = build_net(road, nets)
    assert net_problem(path, road) is None
    for suffix in ("nod", "edg"):
        assert (user / f"{suffix}.xml").read_text() == "<my own file/>\n"
        written, tag = nets / f"{stem}.{suffix}.xml", "<nodes>" if suffix == "nod" else "<edges>"
        assert not written.is_symlink() and written.read_text().startswith(tag)
    assert sorted(p.name for p in nets.iterdir()) == sorted(f"{stem}.{s}.xml" for s in ("nod", "edg", "net"))


@pytest.mark.parametrize("command", ["coopsumo.agents.train_cli", "coopsumo.simulate"])
def test_a_link_that_leads_nowhere_is_refused_up_front(command: str, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 7, I17d: `train --out lnk`, lnk a link to a folder that is not there, said "cannot write output
    folder lnk: File exists" after 6 s; it is refused as the flag is read, naming the link (a link to a folder yet to be
    made above the --out is fine: test_out_path_problem_accepts_ordinary_paths)."""
    from conftest import main_here

    link = tmp_path / "lnk"
    link.symlink_to(tmp_path / "nowhere" / "t")
    code, stdout, err = main_here(importlib.import_module(command).main,
                                  ["--quiet", "--steps", "300", "--out", str(link)], capsys)  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1 and stdout == "", err
    assert f"--out: '{link}' is a link that leads nowhere" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lnk"] and link.is_symlink()


@pytest.mark.sumo
def test_a_network_netconvert_cannot_write_is_one_line(tmp_path: Path) -> None:
    """Issue 82, probe 19, TB1: under a file-size limit (or a full networks folder) netconvert's network was cut short
    or not written, and simulate, train and scenario1 ended in a RuntimeError traceback; now one line naming the
    network, exit 1, no run folder."""
    nets, out = tmp_path / "nets", tmp_path / "run"
    env = {**os.environ, "COOPSUMO_NETS_DIR": str(nets), "PYTHONPATH": os.pathsep.join(sys.path)}
    res = subprocess.run(["bash", "-c", f'ulimit -f 2; exec "{sys.executable}" -m coopsumo simulate --lanes 6 '
                          f'--steps 20 --quiet --out "{out}"'], capture_output=True, text=True, env=env, timeout=300,
                         check=False)  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(lines) == 1 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert lines[0].startswith("simulate: error: netconvert could not build the network (") and \
        lines[0].endswith("highway_6lanes_2000m_w3.2_v33.34.net.xml"), lines  # fmt: skip
    assert not out.exists() and not list(nets.glob("*.net.xml"))
