"""Runs seen and checked with SUMO's own tools: sumo-gui (live view, screenshot), FCD and tripinfo output,
plot_trajectories.py. The commands of docs/sumo-tools.md for them are the ones run here."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import sumolib
from conftest import TIMING_KEYS, env_with_display, main_here
from PIL import Image

from coopsumo.sim import view
from coopsumo.sim.world import GUI_SHOT

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent
PAGE = (ROOT / "docs" / "sumo-tools.md").read_text()
"""the page that documents SUMO's tools on coopsumo's runs"""
PNG = b"\x89PNG\r\n\x1a\n"


def page_lines(marker: str) -> list[str]:
    """The page's bash lines containing marker, continuation lines joined, comments dropped."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", PAGE, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+", " ", line.split(" #")[0]).strip()
            if marker in line and not line.startswith("#"):
                lines.append(line)
    return lines


def simulate(args: list[str], env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo.simulate", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300, check=False)  # fmt: skip


def simulate_here(args: list[str], capsys: pytest.CaptureFixture[str]) -> subprocess.CompletedProcess[str]:
    """simulate's main in this process, for refusals made before SUMO starts (the one-line refusal of a command run
    as a process: tests/test_bad_inputs.py)."""
    from coopsumo import simulate as simulate_command

    code, out, err = main_here(simulate_command.main, args, capsys)
    return subprocess.CompletedProcess(args, code, out, err)


def without_wall(summary_path: Path) -> dict[str, Any]:
    return {k: v for k, v in json.loads(summary_path.read_text()).items() if k not in TIMING_KEYS}


def colours_of(png: Path) -> Counter[tuple[int, int, int]]:
    pixels = np.asarray(Image.open(png).convert("RGB")).reshape(-1, 3)
    return Counter(map(tuple, pixels.tolist()))


def assert_one_line_usage_error(proc: subprocess.CompletedProcess[str], named: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and named in lines[0] and "error" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""


# -- pure -----------------------------------------------------------------------------------
def test_vehicle_states_follow_the_precedence_held_changing_slow_cruising() -> None:
    speed = np.array([20.0, 4.9, 5.0, 1.0, 1.0, 0.0])
    changing = np.array([False, False, False, True, True, False])
    held = np.array([False, False, False, False, True, True])
    states = view.vehicle_states(speed, changing, held)
    assert states.tolist() == [view.CRUISING, view.SLOW, view.CRUISING, view.CHANGING, view.HELD, view.HELD]
    assert len({tuple(c) for c in view.STATE_RGBA.tolist()}) == len(view.STATE_NAMES)  # distinguishable


# -- sumo-gui ---------------------------------------------------------------------------------
def test_documented_gui_command_shows_the_run_and_saves_a_screenshot(tmp_path: Path, gui_display: str) -> None:
    """The page's --gui command under a (virtual) display: sumo-gui's PNG shows the colours of the
    controller's states and the accident bar, and the run is the one libsumo makes without --gui. The run ends at
    the screenshot's step (the page's run goes on past it; the window shows nothing more)."""
    (cmd,) = [c for c in page_lines("--gui ") if c.startswith("coopsumo simulate")]
    args = shlex.split(cmd.replace("results/", f"{tmp_path}/"))[2:] + ["--quiet", "--trajectories"]
    assert int(args[args.index("--steps") + 1]) >= int(args[args.index("--gui-screenshot-step") + 1])
    args[args.index("--steps") + 1] = args[args.index("--gui-screenshot-step") + 1]
    proc = simulate(args, env_with_display(gui_display))
    assert proc.returncode == 0, proc.stderr[-2000:]
    shot = Path(args[args.index("--gui-screenshot") + 1])
    assert shot.read_bytes().startswith(PNG) and shot.stat().st_size > 1000
    colours = colours_of(shot)
    assert len(colours) >= 4 and max(colours.values()) < 0.9 * sum(colours.values())  # not one flat colour
    seen = set(colours)
    assert tuple(view.ACCIDENT_ACTIVE_RGBA[:3]) in seen  # the accident bar
    assert tuple(view.STATE_RGBA[view.HELD][:3]) in seen and tuple(view.STATE_RGBA[view.SLOW][:3]) in seen

    out = Path(args[args.index("--out") + 1])
    gui_flags = ("--gui", "--gui-screenshot", "--gui-screenshot-step")
    plain = [a for i, a in enumerate(args) if a not in gui_flags and args[i - 1] not in gui_flags[1:]]
    plain[plain.index("--out") + 1] = str(tmp_path / "libsumo")
    proc = simulate(plain)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert without_wall(out / "summary.json") == without_wall(tmp_path / "libsumo" / "summary.json")
    gui_traj = pd.read_parquet(out / "trajectories.parquet")
    assert gui_traj.equals(pd.read_parquet(tmp_path / "libsumo" / "trajectories.parquet"))
    assert json.loads((out / "config.json").read_text())["gui"]["screenshot"] == str(shot)
    assert not (out / GUI_SHOT).exists()  # saved in the run's folder, then placed at the path asked for


def test_a_file_made_at_the_screenshot_path_during_the_run_is_kept(tmp_path: Path, gui_display: str) -> None:
    """Issue 82, probe 15, D1: the screenshot path was checked at the run's start and written at its end: a file made
    there meanwhile (a user's, another run's screenshot) was replaced, exit 0. It is kept: one line, exit 2, no run."""
    shot, out = tmp_path / "shot.png", tmp_path / "run"
    args = [sys.executable, "-m", "coopsumo.simulate", "--steps", "200", "--gui-delay", "20", "--quiet", "--gui",
            "--gui-screenshot", str(shot), "--gui-screenshot-step", "10", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(args, cwd=ROOT, env=env_with_display(gui_display), text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".run.partial-*/config.json")):  # the run has started
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.05)
        shot.write_bytes(b"MY NOTES")
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        proc.kill()
    assert proc.returncode == 2 and stdout == "", stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "--gui-screenshot" in lines[0] and "made there while the run went" in lines[0], stderr
    assert shot.read_bytes() == b"MY NOTES" and sorted(p.name for p in tmp_path.iterdir()) == ["shot.png"]


def test_gui_without_a_display_is_one_line_and_exit_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.delenv("DISPLAY", raising=False)
    out = tmp_path / "run"
    proc = simulate_here(["--steps", "50", "--quiet", "--gui", "--out", str(out)], capsys)
    assert_one_line_usage_error(proc, "display")
    assert list(tmp_path.iterdir()) == []


GUI_BAD_INPUTS = [
    (["--gui-screenshot", "x.png"], "needs --gui"),
    (["--gui", "--gui-screenshot", "x.jpg"], ".png"),
    (["--gui", "--gui-screenshot", "x.png", "--gui-screenshot-step", "51"], "--gui-screenshot-step"),
    (["--fcd", "--fcd-period", "0.25"], "multiple"),
    (["--fcd-period", "2"], "needs --fcd"),
]


@pytest.mark.parametrize(("extra", "named"), GUI_BAD_INPUTS, ids=[" ".join(a) for a, _ in GUI_BAD_INPUTS])
def test_bad_gui_and_output_options_are_one_line_and_exit_2(tmp_path: Path, extra: list[str], named: str,
                                                            monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.chdir(tmp_path)  # x.png, x.jpg: never written
    proc = simulate_here(["--steps", "50", "--quiet", "--out", str(tmp_path / "run"), *extra], capsys)
    assert_one_line_usage_error(proc, named)
    assert list(tmp_path.iterdir()) == []


def _screenshot_places(root: Path) -> dict[str, Path]:
    """Screenshot paths simulate may not write (issue 82, probe 7, I2): a user's file, a study's figure, a file in the
    model store, a file inside this run's own --out; each with what must stay as it is."""
    from coopsumo.run_dirs import mark_run_dir

    user = root / "shot.png"
    user.write_bytes(b"precious")
    study = root / "s1"
    study.mkdir()
    mark_run_dir(study, "scenario1", finished=False, study="the quick profile's study")
    (study / "fig4_trajectories.png").write_bytes(b"figure")
    store = root / "models"
    (store / "quick_a0_seed0_0123456789ab").mkdir(parents=True)
    return {"exists": user, "study": study / "fig4_trajectories.png", "store": store / "shot.png",
            "new file in a study": study / "new.png", "inside --out": root / "run" / "shot.png"}  # fmt: skip


@pytest.mark.parametrize("case", ["exists", "study", "store", "new file in a study", "inside --out"])
def test_a_screenshot_is_refused_where_an_output_may_not_go(tmp_path: Path, case: str, monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv("DISPLAY", ":0")  # refused before the display is used: no sumo-gui starts
    shot = _screenshot_places(tmp_path)[case]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    proc = simulate_here(["--steps", "50", "--quiet", "--gui", "--gui-screenshot", str(shot), "--out",
                          str(tmp_path / "run")], capsys)  # fmt: skip
    assert_one_line_usage_error(proc, "--gui-screenshot")
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    assert not (tmp_path / "run").exists() and (case in ("exists", "study") or not shot.exists())


# -- FCD and tripinfo -------------------------------------------------------------------------------
RUN_ARGS = ["--scenario", "accident", "--policy", "sumo", "--steps", "2000", "--accident-start", "300",
            "--accident-steps", "600", "--seed", "3", "--quiet", "--trajectories"]  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The same accident run with SUMO's own models (they draw from SUMO's random numbers every step)
    with --fcd --tripinfo, and without."""
    root = tmp_path_factory.mktemp("tools")
    with_outputs, plain = root / "with", root / "plain"
    for out, extra in ((with_outputs, ["--fcd", "--tripinfo"]), (plain, [])):
        proc = simulate([*RUN_ARGS, "--out", str(out), *extra])
        assert proc.returncode == 0, proc.stderr[-2000:]
    return with_outputs, plain


def test_outputs_do_not_change_the_simulation(runs: tuple[Path, Path]) -> None:
    with_outputs, plain = runs
    assert {p.name for p in with_outputs.iterdir()} - {p.name for p in plain.iterdir()} == {"fcd.xml", "tripinfo.xml"}
    assert without_wall(with_outputs / "summary.json") == without_wall(plain / "summary.json")
    assert pd.read_parquet(with_outputs / "trajectories.parquet").equals(
        pd.read_parquet(plain / "trajectories.parquet")
    )


def test_tripinfo_agrees_with_the_summary(runs: tuple[Path, Path]) -> None:
    out = runs[0]
    summary = json.loads((out / "summary.json").read_text())
    trips = list(sumolib.xml.parse(str(out / "tripinfo.xml"), "tripinfo"))
    assert summary["arrived"] > 50
    assert len(trips) == summary["arrived"]
    assert len(trips) / (summary["sim_seconds"] / 3600) == pytest.approx(summary["throughput_veh_per_h"], rel=1e-9)
    mean_duration = np.mean([float(t.duration) for t in trips])
    assert mean_duration == pytest.approx(summary["mean_travel_time_s"], abs=0.005)  # half SUMO's 0.01 s precision
    traj = pd.read_parquet(out / "trajectories.parquet")
    on_road_at_end = set(traj.loc[traj["time_s"] == traj["time_s"].max(), "vid"].tolist())
    assert {int(t.id) for t in trips} == set(traj["vid"].tolist()) - on_road_at_end


def test_fcd_is_the_controlled_traffic_of_the_trajectories(runs: tuple[Path, Path]) -> None:
    """Every FCD record (SUMO time t) is a trajectory row at time_s = t + 0.1 s, and none is missing."""
    out = runs[0]
    rows = [(float(ts.time), int(v.id), v.lane, float(v.x), float(v.y), float(v.speed))
            for ts in sumolib.xml.parse(str(out / "fcd.xml"), "timestep") for v in ts.getChild("vehicle")]  # fmt: skip
    fcd = pd.DataFrame(rows, columns=["t", "vid", "lane_id", "x", "y", "speed"])
    assert set(np.round(np.diff(np.unique(fcd["t"])), 6)) == {1.0}  # the default period
    traj = pd.read_parquet(out / "trajectories.parquet")
    traj["t"] = np.round(traj["time_s"].astype(float) - 0.1, 3)
    sampled = traj[np.isclose(traj["t"] % 1.0, 0.0) | np.isclose(traj["t"] % 1.0, 1.0)]
    merged = fcd.merge(sampled, on=["t", "vid"], how="outer", indicator=True)
    assert (merged["_merge"] == "both").all(), merged[merged["_merge"] != "both"].head()
    assert (merged["lane_id"] == "road_" + merged["lane"].astype(str)).all()
    assert np.abs(merged["x"] - merged["pos_m"]).max() <= 0.011  # FCD prints 2 decimals; parquet is float32
    assert np.abs(merged["speed"] - merged["speed_mps"]).max() <= 0.011
    assert len(merged) > 1000


def test_sumo_headers_name_the_run_files_by_name(runs: tuple[Path, Path]) -> None:
    """SUMO heads each output with its command line; a run written into a temporary folder and moved had them name
    that folder, gone since: they name the run's files by file name, each one beside them."""
    out = runs[0]
    for name in ("detectors.xml", "fcd.xml", "tripinfo.xml"):
        head = (out / name).read_text()[:4000].split("-->")[0]
        values = dict(re.findall(r"<([a-z.-]+) value=\"([^\"]*)\"/>", head))
        assert ".partial-" not in head and str(out) not in head, name
        named = [values[k] for k in ("route-files", "additional-files", "fcd-output", "tripinfo-output")]
        assert named == ["routes.rou.xml", "detectors.add.xml", "fcd.xml", "tripinfo.xml"], name
        assert all((out / n).is_file() for n in named)
        assert Path(values["net-file"]).is_file()  # the network, outside the run folder, by its path


def test_a_header_loses_its_folder_and_nothing_else(tmp_path: Path) -> None:
    from coopsumo.sim.output_headers import HEADER_BYTES, name_run_files_by_name

    run = tmp_path / ".run.partial-ab&c"
    run.mkdir()
    body = "".join(f'<interval id="e1_{i}" file="{run}/x.xml"/>\n' for i in range(HEADER_BYTES // 20))
    text = (f'<?xml version="1.0"?>\n<!-- generated\n<route-files value="{run}/routes.rou.xml"/>\n'
            f'<additional-files value="{str(run).replace("&", "&amp;")}/detectors.add.xml"/>\n-->\n{body}')
    (run / "detectors.xml").write_text(text)
    name_run_files_by_name(run / "detectors.xml", run)
    got = (run / "detectors.xml").read_text()
    assert got.split("-->")[0].count(run.name) == 0
    assert '<route-files value="routes.rou.xml"/>' in got and '<additional-files value="detectors.add.xml"/>' in got
    assert got.split("-->", 1)[1] == text.split("-->", 1)[1]  # the data past the header, byte for byte
    assert sorted(p.name for p in run.iterdir()) == ["detectors.xml"]  # no working file left
    name_run_files_by_name(run / "missing.xml", run)  # an output not asked for: nothing to do


def test_documented_tripinfo_snippet_runs(runs: tuple[Path, Path]) -> None:
    (snippet,) = [b for b in re.findall(r"```python\n(.*?)```", PAGE, flags=re.S) if '"tripinfo"' in b]
    code = snippet.replace("results/tools/keep/", f"{runs[0]}/")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    summary = json.loads((runs[0] / "summary.json").read_text())
    assert res.stdout.split()[0] == str(summary["arrived"])


def test_documented_fig4_commands_make_their_run_and_draw_a_png(tmp_path: Path) -> None:
    """The page's Fig. 4 block as written, on a fresh clone: its simulate command makes the run folder (shortened
    to 1,500 steps, the accident window with it), its plot_trajectories.py command draws that run's fcd.xml."""
    (block,) = [b for b in re.findall(r"```bash\n(.*?)```", PAGE, flags=re.S) if "plot_trajectories.py" in b]
    sim, plot = [re.sub(r"\s+", " ", line).strip() for line in block.replace("\\\n", " ").splitlines()]
    args = shlex.split(sim.replace("results/", f"{tmp_path}/"))
    assert args[:2] == ["coopsumo", "simulate"] and "--fcd" in args
    run = args[args.index("--out") + 1]
    assert f"{run}/fcd.xml" in plot.replace("results/", f"{tmp_path}/")  # the plot reads the run just made
    steps = int(args[args.index("--steps") + 1])
    for flag in ("--accident-start", "--accident-steps"):
        args[args.index(flag) + 1] = str(int(args[args.index(flag) + 1]) * 1500 // steps)
    args[args.index("--steps") + 1] = "1500"
    proc = simulate([*args[2:], "--quiet"])
    assert proc.returncode == 0, proc.stderr[-2000:]
    cmd = plot.replace("results/", f"{tmp_path}/")
    cmd = re.sub(r"(^|\$\()python ", rf"\1{shlex.quote(sys.executable)} ", cmd)  # the page's activated venv
    png = Path(shlex.split(cmd)[shlex.split(cmd).index("-o") + 1])
    res = subprocess.run(["bash", "-c", cmd], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    assert png.read_bytes().startswith(PNG) and png.stat().st_size > 20_000
    assert len(colours_of(png)) > 10


def test_a_screenshot_folder_that_cannot_be_written_is_refused_before_the_run(tmp_path: Path,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 82, probe 15, T1: a screenshot into a read-only file system was found at the run's end, a traceback; the
    folder's writability (os.access, which a read-only mount fails for root too) is checked with the path's rules."""
    from coopsumo import simulate as simulate_command

    folder = tmp_path / "ro"
    folder.mkdir()
    real = simulate_command.os.access
    monkeypatch.setattr(simulate_command.os, "access", lambda p, mode: real(p, mode) and Path(p) != folder)
    problem = simulate_command.screenshot_problem(folder / "new" / "s.png", tmp_path / "run")
    assert problem is not None and f"the folder {folder} cannot be written" in problem
    assert simulate_command.screenshot_problem(tmp_path / "s.png", tmp_path / "run") is None


def test_an_empty_screenshot_is_refused_and_nothing_placed(tmp_path: Path) -> None:
    """Issue 82, probe 15: on a full disk sumo-gui left a screenshot of 0 bytes, placed at the path asked for with
    exit 0. A screenshot that holds no PNG image is one line and nothing at that path; a PNG is placed."""
    from coopsumo.agents.rollout import PNG_SIGNATURE, _place_screenshot
    from coopsumo.errors import UsageError

    shot, path = tmp_path / GUI_SHOT, tmp_path / "shot.png"
    for content in (b"", b"GIF89a\x00\x00"):
        shot.write_bytes(content)
        with pytest.raises(UsageError, match=rf"holds no PNG image \({len(content)} bytes: is the disk full\?\)"):
            _place_screenshot(shot, path)
        assert not path.exists() and not shot.exists()
    shot.write_bytes(PNG_SIGNATURE + b"rest")
    _place_screenshot(shot, path)
    assert path.read_bytes() == PNG_SIGNATURE + b"rest" and not shot.exists()
