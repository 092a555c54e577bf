"""The one study runner: cells on a local process pool or on Ray, each record written atomically, resume, failures.

A cell is a JSON-ready spec (at least "key" and "config") and a module-level function cell_fn(spec, root) -> record
that runs it in a worker process (libsumo allows one SUMO per process) and never raises: its record says
status "ok", "failed" (with the error) or "interrupted". `execute` runs a list of cells on a backend, writes each
finished cell's record to ROOT/cells/<key>.json the moment it arrives, shows one progress bar with an ETA, records
a cell whose worker died (after a solo retry) as failed and goes on, and on SIGINT/SIGTERM stops the workers (a
training saves its checkpoint) and re-raises. A cell may name another cell ("after": key) whose record must be
"ok" before it starts (scenario I: a model's runs wait for its training). Scenario I, scenario II and the
ablation are each a plan (which cells) plus an analysis on top of this module.
"""

from __future__ import annotations

import json
import logging
import math
import multiprocessing as mp
import os
import queue
import re
import signal
import sys
import time
import traceback
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from tqdm import tqdm

from coopsumo.config import OutputConfig, results_view, to_dict
from coopsumo.runio import UsageError, start_parent_watch, versions, write_json
from coopsumo.runio import study_root as claim_study_root

MAX_CRASHES = 2
"""a cell whose worker process died this many times (the last time running alone) is recorded as failed"""
CellFn = Callable[[dict[str, Any], str], dict[str, Any]]
"""cell_fn(spec, root) -> record, a module-level function (it is pickled to the workers)"""
FailedRecord = Callable[[dict[str, Any], str], dict[str, Any]]
"""failed_record(spec, error) -> the record of a cell that could not run (its worker died, its dependency failed)"""


def blank_record(spec: dict[str, Any], fields: Sequence[str], **empty: Any) -> dict[str, Any]:
    """A cell's record before it runs: the spec's `fields`, its configuration, then `empty` (the study's own
    result fields) and no error or summary yet."""
    record = {k: spec.get(k) for k in fields}
    record.update(config=spec["config"], **empty)
    record.update(error=None, traceback=None, summary=None)
    return record


def as_failed(record: dict[str, Any], error: str) -> dict[str, Any]:
    """`record` (a blank one) as the record of a cell whose worker died or that could not run."""
    record.update(status="failed", error=error, cell_wall_s=None, cell_cpu_s=None, versions=versions())
    return record


def run_recorded(record: dict[str, Any], body: Callable[[], None]) -> dict[str, Any]:
    """Run body (which fills record) and add status, error, wall and CPU time (s) and versions; never raises.

    status "ok", "failed" (with the error's first line and a short traceback) or "interrupted"
    (KeyboardInterrupt, also raised for SIGTERM/SIGINT while training).
    """
    start, cpu_start = time.perf_counter(), time.process_time()
    try:
        body()
        record["status"] = "ok"
    except KeyboardInterrupt as err:
        record.update(status="interrupted", error=f"{type(err).__name__}: {err}")
    except Exception as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""
        record.update(status="failed", error=f"{type(err).__name__}: {first}".rstrip(": "),
                      traceback=traceback.format_exc(limit=8))  # fmt: skip
    record["cell_wall_s"] = round(time.perf_counter() - start, 2)
    record["cell_cpu_s"] = round(time.process_time() - cpu_start, 2)
    record["versions"] = versions()
    return record


def finished_training(out: Path, config: dict[str, Any]) -> dict[str, Any] | None:
    """The training summary of a training without evaluation that finished in out with exactly this config
    (its run marker lists its files, its config.json holds config, model.pt and train_summary.json exist);
    None otherwise. A cell killed after its training but before its record was written reuses it."""
    from coopsumo.runio import RUN_MARKER

    try:
        marker = json.loads((out / RUN_MARKER).read_text())
        stored = json.loads((out / "config.json").read_text())["config"]
        summary = json.loads((out / "train_summary.json").read_text())
    except (OSError, ValueError, KeyError, TypeError):
        return None
    done = isinstance(marker, dict) and marker.get("kind") == "train" and isinstance(marker.get("files"), list)
    if not (done and "model.pt" in marker["files"] and (out / "model.pt").is_file() and isinstance(summary, dict)):
        return None
    if (problem := model_folder_problem(out)) is not None:  # a model that does not load or is not this training's
        print(f"coopsumo: training folder {out} {problem}; training it again", file=sys.stderr)
        return None
    return summary if results_view(stored) == results_view(json.loads(json.dumps(config))) else None


@dataclass(frozen=True)
class CellRecords:
    """The record layout of one study's cells, and the three things every study does with it.

    fields: copied from the cell's spec; empty: the study's own result fields, None until the cell has run;
    extra(spec): fields that depend on the cell (its folder, say).
    """

    fields: tuple[str, ...]
    empty: tuple[str, ...] = ()
    extra: Callable[[dict[str, Any]], dict[str, Any]] | None = None

    def new(self, spec: dict[str, Any]) -> dict[str, Any]:
        """A cell's record before it runs: what it is and where it writes; nothing measured yet."""
        record = blank_record(spec, self.fields, **dict.fromkeys(self.empty))
        if self.extra is not None:
            record.update(self.extra(spec))
        return record

    def failed(self, spec: dict[str, Any], error: str) -> dict[str, Any]:
        """The record of a cell whose worker died or that could not run (execute's failed_record)."""
        return as_failed(self.new(spec), error)

    def run(self, spec: dict[str, Any], body: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
        """Run one cell in this process: body(record) fills the new record (run_recorded); never raises."""
        record = self.new(spec)
        return run_recorded(record, lambda: body(record))


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
    `outputs` asks for and, for a model's run, was made after the model file was written (a retrained model keeps
    its path), and its values and files can be trusted (run_folder_problem; else one line on stderr)."""
    if not ((out / "summary.json").exists() and same_config(out / "config.json", cfg)):
        return False
    if model is not None and not (model.exists() and (out / "summary.json").stat().st_mtime >= model.stat().st_mtime):
        return False
    try:
        recorded = json.loads((out / "config.json").read_text()).get("sumo_outputs")
    except (OSError, ValueError):
        return False
    files = (["fcd.xml"] if outputs.fcd_period_s > 0 else []) + (["tripinfo.xml"] if outputs.tripinfo else [])
    if not (recorded == to_dict(outputs) and all((out / f).exists() for f in files)):
        return False
    if problem := run_folder_problem(out, RUN_SUMMARY):  # its values and files, not only its configuration
        print(f"{prog}: run folder {out} {problem}; running it again", file=sys.stderr)
        return False
    return True


def train_resuming(config: dict[str, Any], out: Path) -> tuple[dict[str, Any], int | None]:
    """Train the TrainConfig dict `config` into out, resuming a checkpoint there made with exactly this config.

    Returns train()'s summary and the step resumed from (None: started afresh). A stop by signal
    becomes KeyboardInterrupt.
    """
    import torch

    from coopsumo.agents.train import Interrupted, Trainer, train
    from coopsumo.config import train_config_from_dict

    torch.set_num_threads(1)
    cfg = train_config_from_dict(config)
    out.mkdir(parents=True, exist_ok=True)
    if cfg.eval_steps == 0 and (stored := finished_training(out, config)) is not None:
        return stored, cfg.sim.steps
    resumed_from = None
    if (out / "checkpoint.pt").exists():
        try:
            state = Trainer.load_checkpoint(out)
            if results_view(json.loads(json.dumps(state["config"]))) == results_view(config):
                resumed_from = int(state["step"])
        except Exception:  # a damaged checkpoint: start afresh
            resumed_from = None
    try:
        summary = train(cfg, out, resume=resumed_from is not None, progress=False)
    except Interrupted as err:
        raise KeyboardInterrupt(str(err)) from err
    return summary, resumed_from


def train_shared(config: dict[str, Any], out: Path) -> tuple[dict[str, Any], int | None]:
    """train_resuming under a lock on out (a file beside it): cells that share one training (the margin variants,
    a conditioned model's alphas) wait for the first to train it, then reuse it."""
    import fcntl

    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return train_resuming(config, out)


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
    "scenario2": ("sweep.json", "cells", "train", "mobil", "runs.csv", "alpha_star.csv", "mobil_p_star.csv",
                  "fig6_*.png", "report.md"),
    "ablation": ("study.json", "cells", "train", "baselines", "runs.csv", "summary.csv", "fig_*.png", "report.md"),
    "regime_map": ("plan.json", "cells", "runs", "runs.csv", "report.md"),
    "protocol": ("study.json", "cells", "train", "runs", "runs.csv", "stats.csv", "diagnosis.csv", "fig_*.png",
                 "report.md"),
}  # fmt: skip
"""the names each study writes at the top of its root, its plan file first (runio.check_study_root)"""


def study_root(root: Path, kind: str) -> AbstractContextManager[Path]:
    """Claim the study root for the block (runio.study_root: path checked, lock held, ownership checked, marked)."""
    return claim_study_root(root, kind, (*STUDY_OUTPUTS[kind], "*.tmp"))


def cell_path(root: Path, key: str) -> Path:
    return root / "cells" / f"{key}.json"


def read_record(root: Path, spec: dict[str, Any]) -> dict[str, Any] | None:
    """The stored record of this cell if it is a JSON object made with this configuration (config.results_view)."""
    try:
        record = json.loads(cell_path(root, spec["key"]).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or results_view(record.get("config")) != results_view(spec["config"]):
        return None
    return record


COUNTS = ("departed", "arrived", "collisions", "teleports", "lane_changes", "lane_changes_rejected",
          "insertion_blocked", "insertion_pending_at_end", "steps")  # fmt: skip
"""summary values that count something: whole numbers >= 0"""
MAX_SPEED_MPS = 50.0
"""no run's speed is above this (1.5 x the road's 33.34 m/s limit, which no vehicle's expected speed exceeds)"""
MAX_LANE_FLOW_VEH_H = 36_000.0
"""no lane carries more than one vehicle per 0.1 s step"""
MAX_LANES = 6


def implausible(summary: dict[str, Any]) -> str | None:
    """Why a summary's values cannot come from a run, or None: counts negative or fractional, a speed outside
    0..MAX_SPEED_MPS, a negative rate, time or share, a throughput above MAX_LANES lanes at MAX_LANE_FLOW_VEH_H."""
    for key, value in summary.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            continue  # record_problem judges the values a study reads
        if key in COUNTS and (value < 0 or value != int(value)):
            return f"has summary {key} = {value}, not a count (a whole number >= 0)"
        if key.endswith("_mps") and not key.startswith("table_") and not 0 <= value <= MAX_SPEED_MPS:
            return f"has summary {key} = {value:g} m/s, outside 0 to {MAX_SPEED_MPS:g} (no run drives so)"
        if key == "throughput_veh_per_h" and not 0 <= value <= MAX_LANES * MAX_LANE_FLOW_VEH_H:
            return f"has summary {key} = {value:g}, more than {MAX_LANES} lanes can carry"
        if key.endswith(("_per_vehicle", "_veh_h", "_time_s", "_share")) and value < 0:
            return f"has summary {key} = {value:g}, below 0"
    number = {k: float(v) for k, v in summary.items() if isinstance(v, int | float) and not isinstance(v, bool)}
    if number.get("arrived", 0.0) > number.get("departed", math.inf):
        return f"has summary arrived = {number['arrived']:g} above departed = {number['departed']:g}"
    if {"lane_changes", "departed", "lane_changes_per_vehicle"} <= set(number) and number["departed"] > 0:
        ratio = number["lane_changes"] / number["departed"]
        if not math.isclose(ratio, number["lane_changes_per_vehicle"], rel_tol=1e-3, abs_tol=1e-3):
            return (f"has summary lane_changes = {number['lane_changes']:g} for {number['departed']:g} vehicles, but "
                    f"lane_changes_per_vehicle = {number['lane_changes_per_vehicle']:g}: edited?")  # fmt: skip
    return None


def record_problem(record: Any, required: Sequence[str]) -> str | None:
    """Why a stored record cannot be trusted, or None: it must be a JSON object of status "ok" with a non-empty
    summary object whose `required` values (the ones the study reads) are finite numbers."""
    if not isinstance(record, dict):
        return f"is a JSON {type(record).__name__}, not an object"
    if "status" not in record:
        return "has no status"
    if record["status"] != "ok":
        return f"has status {json.dumps(record['status'])[:40]}, not \"ok\""
    summary = record.get("summary")
    if not isinstance(summary, dict) or not summary:
        return f"has status ok but its summary is {json.dumps(summary)[:40]}"
    for key in required:
        value = summary.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            return f"has summary {key} = {json.dumps(value)[:40]}, not a number"
        if not math.isfinite(value):
            return f"has summary {key} = {value}, not a finite number"
    return implausible(summary)


def checked_record(record: dict[str, Any], required: Sequence[str]) -> dict[str, Any]:
    """A record just run, as the study may count it: one of status ok that record_problem faults counts as failed."""
    problem = record_problem(record, required) if record.get("status") == "ok" else None
    return {**record, "status": "failed", "error": f"record {problem}"} if problem else record


def reusable_keys(root: Path, specs: Sequence[dict[str, Any]], prog: str, required: Sequence[str]) -> set[str]:
    """The cells whose stored record can be reused: one record_problem accepts, made with the cell's
    configuration. Every other cell is rerun; a record that is neither failed nor interrupted and yet not
    accepted (unreadable, the wrong shape, a bad summary) gets one line on stderr saying why."""
    done = set()
    for spec in specs:
        path = cell_path(root, spec["key"])
        try:
            record = json.loads(path.read_text())
        except FileNotFoundError:
            continue
        except (OSError, ValueError) as err:
            print(f"{prog}: cell {spec['key']}: record {path} is unreadable ({type(err).__name__}); rerunning it",
                  file=sys.stderr)  # fmt: skip
            continue
        if isinstance(record, dict) and record.get("status") in ("failed", "interrupted"):
            continue  # rerun without a word: the study counts these
        problem = record_problem(record, required)
        if problem:
            print(f"{prog}: cell {spec['key']}: record {path} {problem}; rerunning it", file=sys.stderr)
        elif results_view(record.get("config")) == results_view(spec["config"]):
            done.add(spec["key"])
    return done


def summary_problem(path: Path, required: Sequence[str]) -> str | None:
    """Why the summary.json at `path` cannot be trusted, or None: a readable JSON object whose `required` values
    are finite numbers (as record_problem asks of a cell record's summary)."""
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        return f"has an unreadable summary.json ({type(err).__name__})"
    problem = record_problem({"status": "ok", "summary": summary}, required)
    if problem is None:
        return None
    return problem.replace("has status ok but its summary is", "has summary.json").replace("has summary ",
                                                                                             "has summary.json ")


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


def model_folder_problem(folder: Path) -> str | None:
    """Why the training folder's model.pt cannot be reused, or None: the training finished (train's marker lists
    its files; written before markers: train_summary.json is there) and the model loads (dqn.load_model)."""
    from coopsumo.agents.dqn import ModelFileError, load_model
    from coopsumo.runio import RUN_MARKER, finished_run

    if (folder / RUN_MARKER).exists():
        if not finished_run(folder, "train"):
            return "is from a training that has not finished"
    elif not (folder / "train_summary.json").exists():
        return "has no train_summary.json (its training has not finished)"
    try:
        _, meta = load_model(folder / "model.pt")
    except ModelFileError as err:
        return f"cannot be used: {err}"
    try:
        recorded = json.loads((folder / "config.json").read_text())["config"]
    except (OSError, ValueError, KeyError, TypeError):
        return None  # nothing to compare with (the caller checked config.json against the study's configuration)
    if (where := first_difference(meta.get("config"), recorded)) is not None:
        return f"holds a model.pt made by another configuration than its config.json ({where}): swapped?"
    return None


def first_difference(a: Any, b: Any, path: str = "config") -> str | None:
    """Where two configurations (config.results_view of each) first differ, as 'config.sim.seed: 2 != 0'; None
    when they are equal."""
    a, b = results_view(json.loads(json.dumps(a))), results_view(json.loads(json.dumps(b)))

    def walk(x: Any, y: Any, at: str) -> str | None:
        if isinstance(x, dict) and isinstance(y, dict):
            for key in sorted(set(x) | set(y)):
                if (found := walk(x.get(key), y.get(key), f"{at}.{key}")) is not None:
                    return found
            return None
        return None if x == y else f"{at}: {json.dumps(x)[:40]} != {json.dumps(y)[:40]}"

    return walk(a, b, path)


def failed_exit(prog: str, failed: Sequence[str], total: int, root: Path) -> int:
    """A study's exit code: 0, or 1 with one line on stderr naming the failed cells."""
    if not failed:
        return 0
    print(f"{prog}: error: {len(failed)} of {total} cells failed ({', '.join(failed)}); records in {root / 'cells'}; "
          "rerun the same command to retry them", file=sys.stderr)  # fmt: skip
    return 1


def _init_worker(parent_pid: int, pids: Any) -> None:
    """Pool initializer: exit with the main process, and tell it this worker's pid (for abort)."""
    start_parent_watch(parent_pid)
    pids.put(os.getpid())


class LocalBackend:
    """A spawn-context process pool; one cell per worker at a time, at most `workers` in flight."""

    name = "local"

    def __init__(self, workers: int, cell_fn: Callable[[dict[str, Any], str], dict[str, Any]]):
        self.slots = workers
        self._cell_fn = cell_fn
        self._ctx = mp.get_context("spawn")
        self._pids: Any = self._ctx.Queue()  # every worker's pid, put there by _init_worker
        self._worker_pids: set[int] = set()
        self._generation = 0
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.slots, mp_context=self._ctx, initializer=_init_worker,
                                   initargs=(os.getpid(), self._pids))  # fmt: skip

    def _renew(self) -> None:
        """Replace a broken pool (a worker died) by a fresh one; its other futures fail as BrokenProcessPool."""
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._generation += 1
        self._pool = self._new_pool()

    def submit(self, spec: dict[str, Any], root: Path) -> Any:
        try:
            future = self._pool.submit(self._cell_fn, spec, str(root))
        except BrokenProcessPool:  # the pool broke before wait() saw the dead worker's future
            self._renew()
            future = self._pool.submit(self._cell_fn, spec, str(root))
        return (self._generation, future)

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, dict[str, Any] | BaseException]]:
        """Finished handles with their record, or the exception that stopped their worker."""
        futures: dict[Future[dict[str, Any]], Any] = {h[1]: h for h in handles}
        done, _ = wait_futures(list(futures), timeout=timeout, return_when=FIRST_COMPLETED)
        results: list[tuple[Any, dict[str, Any] | BaseException]] = []
        for fut in done:
            err = fut.exception()
            results.append((futures[fut], err if err is not None else fut.result()))
            if isinstance(err, BrokenProcessPool) and futures[fut][0] == self._generation:
                self._renew()
        return results

    def abort(self) -> None:
        """Stop the workers: SIGTERM (a training saves its checkpoint), then SIGKILL after 15 s.

        The workers are found among multiprocessing.active_children() by the pids they reported on start.
        """
        while True:
            try:
                self._worker_pids.add(self._pids.get(timeout=0.1))
            except queue.Empty:
                break
        procs = [p for p in mp.active_children() if p.pid in self._worker_pids]
        for p in procs:
            p.terminate()
        deadline = time.monotonic() + 15.0
        for p in procs:
            p.join(timeout=max(0.0, deadline - time.monotonic()))
        for p in procs:
            if p.is_alive():
                p.kill()
        self._pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        self._pool.shutdown(wait=True)


class RayBackend:
    """Cells as Ray tasks (num_cpus=1, a fresh worker process per task) on a local instance or a cluster."""

    name = "ray"

    def __init__(self, workers: int, address: str | None,
                 cell_fn: Callable[[dict[str, Any], str], dict[str, Any]]):  # fmt: skip
        import ray

        self._ray = ray
        kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": False}
        if address is None:
            kwargs["num_cpus"] = workers
        try:
            ray.init(address=address, **kwargs)
        except (ConnectionError, ValueError, RuntimeError) as err:
            detail = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            where = f" at {address}" if address else ""
            raise UsageError(f"cannot start or reach Ray{where}: {detail}") from None
        self.slots = max(1, int(ray.cluster_resources().get("CPU", workers)))
        self._task = ray.remote(num_cpus=1, max_calls=1, max_retries=1)(cell_fn)

    def submit(self, spec: dict[str, Any], root: Path) -> Any:
        return self._task.remote(spec, str(root))

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, dict[str, Any] | BaseException]]:
        ready, _ = self._ray.wait(list(handles), num_returns=1, timeout=timeout)
        results: list[tuple[Any, dict[str, Any] | BaseException]] = []
        for ref in ready:
            try:
                results.append((ref, self._ray.get(ref)))
            except Exception as err:
                results.append((ref, err))
        return results

    def abort(self) -> None:
        pass  # close() shuts Ray down, which stops its workers

    def close(self) -> None:
        self._ray.shutdown()


def add_backend_flags(parser: Any) -> None:
    """--backend local|ray and --address, the same on every study."""
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="local process pool or Ray")
    parser.add_argument("--address", default=None, help="Ray cluster address (default: start a local Ray instance)")


def check_backend(backend: str, address: str | None) -> None:
    """Usage errors before anything is written: --address without Ray, Ray not installed, a cluster that does
    not answer (validation.check_ray_address: within 30 s)."""
    from coopsumo.validation import check_ray_address

    if address is not None and backend != "ray":
        raise UsageError("--address is for --backend ray")
    if backend == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise UsageError("--backend ray needs Ray: .venv/bin/pip install 'ray[default]'") from None
        if address is not None:
            check_ray_address("--address", address)


def make_backend(
    name: str, workers: int, address: str | None, cell_fn: Callable[[dict[str, Any], str], dict[str, Any]]
) -> LocalBackend | RayBackend:
    """The execution backend; cell_fn(spec, root) -> record runs one cell (a module-level function)."""
    if name == "local":
        return LocalBackend(workers, cell_fn)
    try:
        import ray  # noqa: F401
    except ImportError:
        raise UsageError("--backend ray needs Ray: .venv/bin/pip install 'ray[default]'") from None
    return RayBackend(workers, address, cell_fn)


def _raise_interrupt(signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM in the main process becomes KeyboardInterrupt, so the workers are stopped cleanly."""
    old = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


@contextmanager
def _signals_ignored() -> Iterator[None]:
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def execute(specs: Sequence[dict[str, Any]], root: Path, backend: LocalBackend | RayBackend, total: int,
            done_before: int, progress: bool, failed_record: FailedRecord, desc: str = "cells",
            done_keys: Sequence[str] = ()) -> dict[str, int]:  # fmt: skip
    """Run the cells in the given order (the order is the priority); write each record the moment it arrives.

    total and done_before size the progress bar (cells of the whole study, cells finished before this call);
    done_keys: cells finished ok before this call (a cell's "after" may name one). Returns counts of ok/failed
    cells. On KeyboardInterrupt (Ctrl-C or SIGTERM) the workers are stopped and the interrupt re-raised.
    """
    (root / "cells").mkdir(parents=True, exist_ok=True)
    todo = list(specs)
    pending = {spec["key"] for spec in specs}  # not finished yet in this call
    ok_keys: set[str] = set(done_keys)
    failed_keys: set[str] = set()
    # A dead worker breaks the whole pool, so every cell in flight sees BrokenProcessPool; such cells
    # are rerun alone ("solo"), where a crash can only be their own, before one is recorded as failed.
    solo: deque[dict[str, Any]] = deque()
    solo_running = False
    inflight: dict[Any, dict[str, Any]] = {}
    crashes: Counter[str] = Counter()
    counts = {"ok": 0, "failed": 0}
    bar = tqdm(total=total, initial=done_before, desc=desc, unit="cell", file=sys.stderr,
               disable=not progress, mininterval=1.0, smoothing=0.1)  # fmt: skip

    def finish(spec: dict[str, Any], record: dict[str, Any]) -> None:
        write_json(cell_path(root, spec["key"]), record)
        pending.discard(spec["key"])
        (ok_keys if record["status"] == "ok" else failed_keys).add(spec["key"])
        counts[record["status"]] += 1
        bar.update(1)

    def startable() -> list[dict[str, Any]]:
        """Cells of todo whose dependency is done (a failed dependency fails them at once)."""
        ready = []
        for spec in list(todo):
            dep = spec.get("after")
            if dep in failed_keys:
                todo.remove(spec)
                finish(spec, failed_record(spec, f"needs cell {dep}, which failed"))
            elif dep is None or dep in ok_keys or dep not in pending:
                ready.append(spec)
        return ready

    try:
        while todo or solo or inflight:
            if solo and not inflight:
                spec = solo.popleft()
                inflight[backend.submit(spec, root)] = spec
                solo_running = True
            if not solo and not solo_running:
                ready = startable()
                if not ready and not inflight and todo:  # only cells waiting on cells that will never run
                    for spec in todo:
                        finish(spec, failed_record(spec, f"needs cell {spec.get('after')}, which did not run"))
                    todo.clear()
                for spec in ready[: max(0, backend.slots - len(inflight))]:
                    todo.remove(spec)
                    inflight[backend.submit(spec, root)] = spec
            bar.refresh()  # the elapsed time moves on while long cells run
            for handle, outcome in backend.wait(list(inflight), timeout=1.0):
                spec = inflight.pop(handle)
                was_solo, solo_running = solo_running, solo_running and bool(inflight)
                if isinstance(outcome, BrokenProcessPool):
                    crashes[spec["key"]] += 1
                    if not (was_solo and crashes[spec["key"]] >= MAX_CRASHES):
                        solo.append(spec)
                        continue
                    record = failed_record(spec, f"worker process died {MAX_CRASHES} times (BrokenProcessPool)")
                elif isinstance(outcome, BaseException):
                    record = failed_record(spec, f"{type(outcome).__name__}: {str(outcome).strip()[:300]}")
                else:
                    record = outcome
                if record["status"] == "interrupted":
                    raise KeyboardInterrupt(f"cell {spec['key']} interrupted")
                finish(spec, record)
                running = len(inflight) + min(len(todo), backend.slots - len(inflight))
                bar.set_postfix(failed=counts["failed"], running=running, refresh=False)
    except KeyboardInterrupt:
        bar.close()
        with _signals_ignored():
            backend.abort()
        raise
    bar.close()
    return counts
