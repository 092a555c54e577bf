"""Scenario I's sumo-gui screenshot of the jam for the report: the run made again in sumo-gui through TraCI at the
step its view is nearly full of slow vehicles, and the report's text about it (or why there is none).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import SimConfig, as_data, to_dict
from coopsumo.errors import UsageError
from coopsumo.files import read_json, read_text, write_json
from coopsumo.sim import view
from coopsumo.studies.scenario1.measures import SLOW_MPS, jam_step

GUI_SHOT = "gui_jam.png"
_SHOWN = re.compile(r"!\[[^\]\n]*\]\(([^)\s]+)\)")


def drop_shown(root: Path, names: Iterable[str]) -> None:
    """Remove the files `names` in the study root `root` that its report.md, the one an earlier run wrote, shows
    (![...](NAME)): that run's figures, which the new report may not show. A file of such a name that it does not
    show is a user's and stays (issue 82, probe 12, N4: fig5_flow_density_t3.png and gui_jam.png were deleted)."""
    try:
        shown = set(_SHOWN.findall(read_text(root / "report.md", errors="replace")))
    except OSError:
        return
    for name in names:
        if name in shown:
            (root / name).unlink(missing_ok=True)


def gui_run(cfg: SimConfig, shot: Path) -> dict[str, list[Any]]:
    """Run cfg's simulation in sumo-gui (through TraCI, so in this process) to its last step and save
    sumo-gui's screenshot of that step to shot. Returns that step's vehicles (vid, lane, pos_m, speed_mps)."""
    import tempfile

    from coopsumo.agents.policies import policy_for_run
    from coopsumo.agents.rollout import run
    from coopsumo.config import GuiConfig

    policy = policy_for_run(cfg)
    gui = GuiConfig(screenshot=str(shot.resolve()), screenshot_step=cfg.steps)
    with tempfile.TemporaryDirectory(prefix="gui-run-") as tmp:
        run(cfg, policy, Path(tmp), trajectories=True, label="sumo-gui screenshot", trajectory_every=cfg.steps, gui=gui)
        last = pd.read_parquet(Path(tmp) / "trajectories.parquet")
    return {k: last[k].tolist() for k in ("vid", "lane", "pos_m", "speed_mps")}


def gui_section(root: Path, run_dir: Path, label: str, cfg: SimConfig, environ: dict[str, str] | None = None) -> str:
    """The report's sumo-gui screenshot of the jam (made, or reused when the same), or a note why there is none."""
    env = os.environ if environ is None else environ
    shot = root / GUI_SHOT
    if not env.get("DISPLAY"):
        drop_shown(root, [GUI_SHOT])  # a picture from an earlier study would not match this one
        return ("No sumo-gui screenshot: no display was available (DISPLAY is not set). Rerun the study under "
                "`xvfb-run -a -s \"-screen 0 1600x900x24\"` to get one; finished runs are reused.")  # fmt: skip
    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    step = jam_step(traj, cfg)
    if step is None:
        drop_shown(root, [GUI_SHOT])
        return f"No sumo-gui screenshot: no vehicle of {label} was slower than {SLOW_MPS:g} m/s near the bottleneck."
    gui_cfg = replace(cfg, steps=step)
    record = root / "gui_jam.json"
    try:
        done = read_json(record)
    except (OSError, ValueError):
        done = {}
    if not (shot.exists() and done.get("config") == as_data(gui_cfg)):
        shot.unlink(missing_ok=True)  # made again here, at a name the study writes (rollout checks it was made)
        try:
            last = gui_run(gui_cfg, shot)
        except UsageError as err:  # DISPLAY is set but sumo-gui cannot open it: the study's results stand
            return f"No sumo-gui screenshot: {err}."
        rows = traj[np.isclose(traj["time_s"], step * cfg.control.dt_s)].sort_values("vid")
        same = last == {k: rows[k].tolist() for k in ("vid", "lane", "pos_m", "speed_mps")}
        done = {"config": to_dict(gui_cfg), "run": label, "step": step, "identical_to_run": same}
        write_json(record, done)
    p = cfg.accident.hold_probability(step)
    names = zip(view.STATE_NAMES, view.STATE_COLOUR_NAMES, strict=True)
    colours = ", ".join(f"{name} {colour}" for name, colour in names)
    same_text = "identical" if done["identical_to_run"] else "NOT identical (a bug: please report)"
    return (
        f"![sumo-gui]({GUI_SHOT})\n\nsumo-gui at step {step} (t = {step * cfg.control.dt_s:.1f} s, stuck ratio "
        f"p = {p:.2f}) of run `runs/{label}/`, made by running it again in sumo-gui through TraCI "
        f"(vehicle positions at that step {same_text} to the recorded run): the {view.VIEW_UPSTREAM_M:.0f} m "
        f"upstream of the bottleneck (red bar), traffic from left to right. Vehicles: {colours}."
    )
