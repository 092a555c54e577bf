"""A training's log: the sums of one logging window (Window), train_log.csv's columns, and TensorBoard scalars of
the run (`coopsumo train --tensorboard`): the numbers of every train_log.csv row, at its step, in OUT/tensorboard/.
The CSV stays the record; TensorBoard is for watching a run live (`tensorboard --logdir OUT/tensorboard`). torch's
SummaryWriter needs the `tensorboard` package (`pip install 'coopsumo[tensorboard]'`; `make install` installs it).
"""

from __future__ import annotations

import argparse
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coopsumo.sim.world import StepOutcome

LOG_FIELDS = (
    "step", "sim_time_s", "td_loss", "r_speed", "r_lane_change", "r_flow", "reward", "epsilon",
    "mean_speed_mps", "vehicles", "lane_changes", "lane_changes_rejected", "collisions", "teleports", "wall_s",
    "alpha",
)  # fmt: skip
"""train_log.csv's columns; alpha: the reward's alpha at the window's last step (drawn, when conditioned)"""


@dataclass
class Window:
    """Sums over one logging window."""

    loss: list[float] = field(default_factory=list)
    r_speed: float = 0.0
    r_lane_change: float = 0.0
    r_flow: float = 0.0
    samples: int = 0
    speed_sum: float = 0.0
    vehicle_steps: int = 0
    lane_changes: int = 0
    rejected: int = 0

    def add(self, out: StepOutcome, speeds: np.ndarray, lane_change_penalty: np.ndarray) -> None:
        """One step: its outcome, the speeds on the road (m/s), and the lane-change reward the learner got."""
        self.r_speed += float(out.reward.speed.sum())
        self.r_lane_change += float(lane_change_penalty.sum())
        self.r_flow += float(out.reward.flow.sum())
        self.samples += len(out.nums)
        self.speed_sum += float(speeds.sum())
        self.vehicle_steps += len(speeds)
        self.lane_changes += int(out.lane_change_started.sum())
        self.rejected += int(out.rejected.sum())


TB_DIR = "tensorboard"
"""folder of the event files inside the training's run folder"""
SCALARS = {
    "td_loss": "loss/td",
    "r_speed": "reward/speed",
    "r_lane_change": "reward/lane_change",
    "r_flow": "reward/flow",
    "reward": "reward/total",
    "epsilon": "learner/epsilon",
    "mean_speed_mps": "traffic/mean_speed_mps",
    "vehicles": "traffic/vehicles",
    "lane_changes": "traffic/lane_changes",
    "lane_changes_rejected": "traffic/lane_changes_rejected",
    "collisions": "traffic/collisions",
    "teleports": "traffic/teleports",
}
"""train_log.csv column -> TensorBoard tag. Rewards are per transition and window (as in the CSV), speed in
m/s, lane changes per window of log_every_steps steps, collisions and teleports since the start"""
MISSING = "--tensorboard needs the tensorboard package: pip install 'coopsumo[tensorboard]'"


def available() -> bool:
    """True when torch's SummaryWriter can be imported (the tensorboard package is installed)."""
    try:
        from torch.utils.tensorboard import SummaryWriter  # noqa: F401
    except ImportError:
        return False
    return True


class TensorBoardFlag(argparse.Action):
    """--tensorboard: on, checked when the command line is read (one-line usage error without the package)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=False, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:  # fmt: skip
        if not available():
            parser.error(MISSING)
        setattr(namespace, self.dest, True)


class ScalarLog:
    """One SummaryWriter on folder; add_row(row) writes a train_log.csv row's numbers at its step."""

    def __init__(self, folder: Path, purge_step: int | None = None) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self._writer = SummaryWriter(log_dir=str(folder), purge_step=purge_step)

    def add_row(self, row: Mapping[str, Any]) -> None:
        step = int(row["step"])
        for column, tag in SCALARS.items():
            value = row.get(column)
            if value is not None and value != "":  # td_loss is empty before the first update
                self._writer.add_scalar(tag, float(value), step)
        self._writer.flush()  # one flush per logging window (1,000 steps): readable while the run goes on

    def close(self) -> None:
        self._writer.close()


def open_log(out: Path, enabled: bool, resume: bool, resumed_step: int = 0) -> ScalarLog | None:
    """The training's ScalarLog in out/TB_DIR, None when not enabled; a fresh (not resumed) training first removes
    the event files an earlier training left in out, so that one folder never mixes two runs. A training resumed
    from its checkpoint at resumed_step hides the points a killed run wrote past it (TensorBoard's purge_step), as
    train_log.csv drops those rows: each step's point is shown once."""
    if not resume:
        shutil.rmtree(out / TB_DIR, ignore_errors=True)
    return ScalarLog(out / TB_DIR, resumed_step + 1 if resume else None) if enabled else None
