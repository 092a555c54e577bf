"""A study's run folders: a run of one configuration into its folder, the roots studies write, and when a
finished run folder can be reused (its configuration, its outputs, its values)."""

from __future__ import annotations

import json
import math
import os
import re
import sys
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

from coopsumo.config import OutputConfig, results_view, to_dict
from coopsumo.runio import file_sha256
from coopsumo.runio import study_root as claim_study_root
from coopsumo.studies.records import MAX_LANE_FLOW_VEH_H, summary_problem

MAX_CRASHES = 2
"""a cell whose worker process died this many times (the last time running alone) is recorded as failed"""
CellFn = Callable[[dict[str, Any], str], dict[str, Any]]
"""cell_fn(spec, root) -> record, a module-level function (it is pickled to the workers)"""
FailedRecord = Callable[[dict[str, Any], str], dict[str, Any]]
"""failed_record(spec, error) -> the record of a cell that could not run (its worker died, its dependency failed)"""


def same_config(path: Path, cfg: dict[str, Any]) -> bool:
    """True when path (a run or training folder's config.json) records this configuration (config.results_view)."""
    try:
        return bool(results_view(json.loads(path.read_text())["config"]) == results_view(json.loads(json.dumps(cfg))))
    except (OSError, ValueError, KeyError):
        return False


RUN_SUMMARY = ("departed", "mean_speed_mps", "throughput_veh_per_h", "lane_changes", "collisions", "teleports")
"""summary.json values a stored accident run must hold as finite numbers to be reused (scenario I's measures)"""


def reusable_run(out: Path, cfg: dict[str, Any], outputs: OutputConfig, model: Path | None = None,
                 prog: str = "scenario1") -> bool:  # fmt: skip
    """True when the run folder out holds a finished run of the SimConfig dict cfg with the SUMO output files
    `outputs` asks for and, for a model's run, was driven by the model file as it is now (model_driven), and its
    values and files can be trusted (run_folder_problem; else one line on stderr)."""
    if not ((out / "summary.json").exists() and same_config(out / "config.json", cfg)):
        return False
    try:
        written = json.loads((out / "config.json").read_text())
        recorded = written.get("sumo_outputs")
    except (OSError, ValueError, AttributeError):
        return False
    if model is not None and not model_driven(out, written, model):
        return False
    files = (["fcd.xml"] if outputs.fcd_period_s > 0 else []) + (["tripinfo.xml"] if outputs.tripinfo else [])
    if not (recorded == to_dict(outputs) and all((out / f).exists() for f in files)):
        return False
    if problem := run_folder_problem(out, RUN_SUMMARY):  # its values and files, not only its configuration
        print(f"{prog}: run folder {out} {problem}; running it again", file=sys.stderr)
        return False
    return True


def model_driven(out: Path, written: Any, model: Path) -> bool:
    """True when the run in out (its config.json: written) was driven by the model file as it is now: the file's
    sha256 recorded at the run equals today's (a retrained model, or a link moved to another model, keeps its
    path). A run written before the digest was recorded: made after the model file was last written."""
    if not model.exists():
        return False
    trained_on = written.get("model_trained_on") if isinstance(written, dict) else None
    digest = trained_on.get("model_sha256") if isinstance(trained_on, dict) else None
    if digest is not None:
        return bool(digest == file_sha256(model))
    return (out / "summary.json").stat().st_mtime >= model.stat().st_mtime


def simulate_into(
    config: dict[str, Any],
    out: Path,
    label: str,
    trajectory_every: int = 0,
    outputs: OutputConfig | None = None,
    atomic: bool = False,
) -> dict[str, Any]:
    """Run the SimConfig dict `config` with its own policy into out; the summary without its policy field.

    trajectory_every: also write trajectories, every this many steps (0: none); outputs: SUMO's FCD and
    tripinfo files; atomic: build the folder aside and move it into place when the run has finished, so a
    killed run leaves no half folder.
    """
    from coopsumo.agents.policies import policy_for_run
    from coopsumo.agents.rollout import run
    from coopsumo.config import sim_config_from_dict
    from coopsumo.runio import atomic_run_dir

    cfg = sim_config_from_dict(config)
    policy = policy_for_run(cfg)
    if not atomic:
        out.mkdir(parents=True, exist_ok=True)
    with atomic_run_dir(out) if atomic else nullcontext(out) as run_dir:
        summary = run(cfg, policy, run_dir, trajectories=trajectory_every > 0, progress=False, label=label,
                      trajectory_every=max(trajectory_every, 1), outputs=outputs)  # fmt: skip
    return {k: v for k, v in summary.items() if k != "policy"}


STUDY_OUTPUTS: dict[str, tuple[str, ...]] = {
    "scenario1": ("plan.json", "cells", "models", "runs", "runs.csv", "summary.csv", "report.md", "fig*.png",
                  "gui_jam.png", "gui_jam.json"),
    "scenario2": ("sweep.json", "cells", "train", "evals", "mobil", "runs.csv", "evals.csv", "alpha_star.csv",
                  "mobil_p_star.csv", "fig6_*.png", "report.md"),
    "ablation": ("study.json", "cells", "train", "baselines", "runs.csv", "summary.csv", "fig_*.png", "report.md"),
    "regime_map": ("plan.json", "cells", "runs", "runs.csv", "report.md"),
    "protocol": ("study.json", "cells", "train", "runs", "runs.csv", "stats.csv", "diagnosis.csv", "fig_*.png",
                 "report.md"),
}  # fmt: skip
"""the names each study writes at the top of its root, its plan file first (runio.check_study_root)"""


def default_out(name: str, profile: str, committed: str) -> Path:
    """A study's results folder when --out is not given: results/<name> for the profile whose report is committed,
    results/<name>_<profile> for any other, so that a quick or test run never replaces a committed report."""
    return Path("results") / (name if profile == committed else f"{name}_{profile}")


def study_root(root: Path, kind: str) -> AbstractContextManager[Path]:
    """Claim the study root for the block (runio.study_root: path checked, lock held, ownership checked, marked)."""
    return claim_study_root(root, kind, (*STUDY_OUTPUTS[kind], "*.tmp"))


def run_folder_problem(out: Path, required: Sequence[str]) -> str | None:
    """Why a finished run folder (simulate's: config.json, summary.json, detectors.xml, maybe trajectories.parquet)
    cannot be reused as it is, or None: marked finished by simulate (or written before markers: no marker at
    all), its summary trusted (summary_problem), detectors.xml complete, trajectories.parquet readable."""
    import pyarrow.parquet as pq

    from coopsumo.runio import RUN_MARKER, finished_run

    if (out / RUN_MARKER).exists() and not finished_run(out, "simulate"):
        return f"has a {RUN_MARKER} that does not mark a finished simulate run"
    if problem := summary_problem(out / "summary.json", required):
        return problem
    try:
        with (out / "detectors.xml").open("rb") as f:
            f.seek(max(0, f.seek(0, os.SEEK_END) - 64))
            complete = f.read().rstrip().endswith(b"</detector>")
    except OSError:
        complete = False
    if not complete:
        return "has a missing or cut-short detectors.xml"
    if problem := detector_flow_problem(out / "detectors.xml"):
        return problem
    if (out / "trajectories.parquet").exists():
        try:
            pq.read_metadata(out / "trajectories.parquet")
        except Exception:  # pyarrow raises several types for a damaged file
            return "has an unreadable trajectories.parquet"
    return None


_FLOW = re.compile(rb'\sflow="([^"]*)"')


def detector_flow_problem(path: Path) -> str | None:
    """Why the loops' flows in an E1 detectors.xml cannot come from a run, or None: every flow="..." a number from
    0 to MAX_LANE_FLOW_VEH_H (a loop lies on one lane)."""
    try:
        text = path.read_bytes()
    except OSError:
        return "has an unreadable detectors.xml"
    for match in _FLOW.finditer(text):
        try:
            flow = float(match.group(1))
        except ValueError:
            flow = math.nan
        if not 0 <= flow <= MAX_LANE_FLOW_VEH_H:
            return (f"has detectors.xml with flow {match.group(1).decode(errors='replace')[:20]} veh/h, outside 0 to "
                    f"{MAX_LANE_FLOW_VEH_H:,.0f} (one vehicle per 0.1 s step on a lane)")  # fmt: skip
    return None
