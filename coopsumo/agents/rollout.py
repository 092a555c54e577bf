"""One simulation run with a policy: the step loop around the World, the decision interval, the run folder's files.

Every command that simulates (simulate, train's evaluation, the studies) runs through `run`.
"""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from coopsumo.agents.adaptive import interval_measures
from coopsumo.agents.decisions import ActionHold
from coopsumo.agents.policies import Policy
from coopsumo.config import SUMO_ROOTS, GuiConfig, OutputConfig, SimConfig, to_dict
from coopsumo.errors import UsageError
from coopsumo.files import write_json, write_new
from coopsumo.provenance import versions
from coopsumo.sim.world import GUI_SHOT, World

ADAPTIVE_ALPHA_FILE = "adaptive_alpha.csv"
"""an adaptive policy's choices: per loop period, the road's loop measurements and the alpha chosen from them"""


def _drive(world: World, cfg: SimConfig, policy: Policy, progress: bool, label: str,
           on_steps: Callable[[int], None] | None) -> None:  # fmt: skip
    """cfg.steps steps of `policy` in the world, with a progress bar; a policy that adapts to the loops'
    measurements (an adaptive rule) is told of every loop period."""
    bar = tqdm(total=cfg.steps, desc=label, unit="step", disable=not progress, mininterval=0.5, file=sys.stderr)
    hold = ActionHold(policy.decision_interval)
    listen = getattr(policy, "loop_interval", None) if getattr(policy, "rule", None) is not None else None
    for _ in range(cfg.steps):
        decide = hold.is_decision_step(world.step_count)
        obs = world.observe(grids=decide and policy.needs_grids)
        world.drive(hold.actions(obs.nums, policy.act(obs) if decide else None))  # no rewards needed
        if listen is not None and world.step_count % world.loop_period_steps == 0:
            counts, occupancy, speeds = world.loop_last_interval()
            listen(interval_measures(world.time_s, counts, occupancy, speeds, cfg.road.loop_period_s))
        if world.step_count % 500 == 0:
            bar.update(500)
            if on_steps is not None:
                on_steps(500)
            bar.set_postfix(
                veh=len(world.table.nums), v=f"{world.table.speed.mean() if len(world.table.nums) else 0:.1f}"
            )
    bar.close()


def run(
    cfg: SimConfig,
    policy: Policy,
    run_dir: Path,
    trajectories: bool = False,
    progress: bool = True,
    label: str = "simulate",
    trajectory_every: int = 1,
    on_steps: Callable[[int], None] | None = None,
    outputs: OutputConfig | None = None,
    gui: GuiConfig | None = None,
) -> dict[str, Any]:
    """Run cfg.steps steps with `policy` in run_dir; write its files; return the summary.

    trajectory_every: record trajectories every k-th step; on_steps(n) is told of progress;
    outputs: SUMO's FCD and tripinfo files; gui: run in sumo-gui (the summary is the same).
    """
    outputs = outputs or OutputConfig()
    write_json(
        run_dir / "config.json",
        {
            "config": to_dict(cfg),
            "versions": versions(),
            "trajectory_every_steps": trajectory_every if trajectories else None,
            "sumo_outputs": to_dict(outputs),
            "gui": to_dict(gui) if gui is not None else None,
            "model_trained_on": getattr(policy, "trained_on", None),
        },
    )
    start = time.perf_counter()
    record_every = trajectory_every if trajectories else 0
    with World(cfg, run_dir, record_trajectories_every=record_every, observe_grids=policy.needs_grids,
               outputs=outputs, gui=gui) as world:  # fmt: skip
        _drive(world, cfg, policy, progress, label, on_steps)
        summary: dict[str, Any] = world.summary()
        sumo_step_s = world.session.step_seconds
        traj = world.trajectories() if trajectories else None
    wall = time.perf_counter() - start
    check_sumo_outputs(run_dir, outputs)
    summary["wall_seconds"] = round(wall, 3)
    summary["steps_per_second"] = round(cfg.steps / wall, 1)
    summary["sumo_step_share"] = round(sumo_step_s / wall, 3)
    summary["policy"] = cfg.policy
    summary["decision_interval_steps"] = policy.decision_interval
    summary["scenario"] = cfg.scenario
    if gui is not None and gui.screenshot:
        _place_screenshot(run_dir / GUI_SHOT, Path(gui.screenshot))
    alpha_log = getattr(policy, "alpha_log", None)
    if alpha_log:
        import pandas as pd

        pd.DataFrame(alpha_log).to_csv(run_dir / ADAPTIVE_ALPHA_FILE, index=False, float_format="%.6g")
        summary["adaptive_alpha_mean"] = round(float(np.mean([r["alpha"] for r in alpha_log])), 4)
    if traj is not None:
        import pandas as pd

        pd.DataFrame(traj).to_parquet(run_dir / "trajectories.parquet", index=False)
    write_json(run_dir / "summary.json", summary)
    return summary


def check_sumo_outputs(run_dir: Path, outputs: OutputConfig) -> None:
    """OSError (EFBIG) naming the first of the XML outputs SUMO wrote into run_dir (detectors.xml, and fcd.xml and
    tripinfo.xml when `outputs` asks for them; a user's file of such a name is not the run's) that does not end with
    its closing tag: SUMO's writer drops what the file system refuses without a word (a file-size limit, `ulimit -f`;
    a full disk), and the run would be marked finished with a cut-short file (issue 82, probe 17, DL1)."""
    import errno

    written = {"detectors.xml": True, "fcd.xml": outputs.fcd_period_s > 0, "tripinfo.xml": outputs.tripinfo}
    for name, closing in SUMO_ROOTS.items():
        path = run_dir / name
        if not written[name] or not path.is_file():
            continue
        with path.open("rb") as f:
            f.seek(max(path.stat().st_size - 256, 0))
            end = f.read()
        if not end.rstrip().endswith(closing):
            raise OSError(errno.EFBIG, f"SUMO's {name} ends cut short at {path.stat().st_size:,} bytes, before "
                          f"{closing.decode()} (a file-size limit, ulimit -f, or a full disk?); the run is not kept",
                          str(path))  # fmt: skip


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
"""the first bytes of every PNG file"""


def _place_screenshot(shot: Path, path: Path) -> None:
    """sumo-gui's screenshot, saved in the run's folder, placed at `path` as a new file (files.write_new: a file made
    there since the run's start, another run's or a user's, is never written over); one line otherwise."""
    if not shot.is_file():
        raise UsageError(f"--gui-screenshot {path}: sumo-gui did not write the screenshot (is the display there?)")
    with shot.open("rb") as f:
        head = f.read(len(PNG_SIGNATURE))
    if head != PNG_SIGNATURE:  # probe 15: a full disk left a file of 0 bytes, placed with exit 0
        size = shot.stat().st_size
        shot.unlink(missing_ok=True)
        raise UsageError(f"--gui-screenshot {path}: sumo-gui's screenshot holds no PNG image ({size} bytes: is the "
                         "disk full?); nothing is written there")  # fmt: skip
    try:
        write_new(path, lambda tmp: shutil.copyfile(shot, tmp))
    except FileExistsError:
        raise UsageError(f"--gui-screenshot {path}: a file was made there while the run went (another run's "
                         "screenshot, or yours); it is left as it is and this run's screenshot is not written: name a "
                         "new file") from None
    finally:
        shot.unlink(missing_ok=True)
