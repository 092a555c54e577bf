"""The one study runner: cells on a local process pool or on Ray, each record written atomically, resume, failures.

A cell is a JSON-ready spec (at least "key" and "config") and a module-level function cell_fn(spec, root) -> record
that runs it in a worker process (libsumo allows one SUMO per process) and never raises: its record says
status "ok", "failed" (with the error) or "interrupted". `execute` runs a list of cells on a backend, writes each
finished cell's record to ROOT/cells/<key>.json the moment it arrives, shows one progress bar naming the cells in
flight (its estimate of the time left once a cell has ended), records a cell whose worker died (after a solo retry)
as failed and goes on, and on SIGINT/SIGTERM stops the workers (a training saves its checkpoint) and re-raises. A
cell may name another cell ("after": key) whose record must be "ok" before it starts (scenario I: a model's runs
wait for its training). Scenario I, scenario II and the ablation are each a plan (which cells) plus an analysis on
top of this module.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

from tqdm import tqdm

from coopsumo.errors import UsageError
from coopsumo.files import write_json
from coopsumo.pool_workers import ParentStreams, init_worker, worker_context
from coopsumo.runio import (
    children_start_deaf,
    raise_swallowed_stop,
)
from coopsumo.studies.engine.records import cell_path

MAX_CRASHES = 2
"""a cell whose worker process died this many times (the last time running alone) is recorded as failed"""
CellFn = Callable[[dict[str, Any], str], dict[str, Any]]
"""cell_fn(spec, root) -> record, a module-level function (it is pickled to the workers)"""
FailedRecord = Callable[[dict[str, Any], str], dict[str, Any]]
"""failed_record(spec, error) -> the record of a cell that could not run (its worker died, its dependency failed)"""


class LocalBackend:
    """A process pool (worker_context); one cell per worker at a time, at most `workers` in flight."""

    name = "local"

    def __init__(self, workers: int, cell_fn: Callable[[dict[str, Any], str], dict[str, Any]]):
        self.slots = workers
        self._cell_fn = cell_fn
        self._ctx = worker_context()
        self._generation = 0
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.slots, mp_context=self._ctx, initializer=init_worker,
                                   initargs=(os.getpid(), dict(os.environ), ParentStreams()))  # fmt: skip

    def _renew(self) -> None:
        """Replace a broken pool (a worker died) by a fresh one; its other futures fail as BrokenProcessPool."""
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._generation += 1
        self._pool = self._new_pool()

    def submit(self, spec: dict[str, Any], root: Path) -> Any:
        """Submit a cell; the pool starts its worker processes here, deaf to Ctrl-C until pool_workers.init_worker."""
        with children_start_deaf():
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

    def abort(self, manager: threading.Thread | None = None) -> None:
        """Stop the workers: SIGTERM (a training saves its checkpoint), then SIGKILL after 15 s.

        The workers are this process's multiprocessing children (multiprocessing.active_children()), those still
        starting included: one left starting would find this process's queues gone and end in a traceback. manager:
        the pool's thread, when a shutdown forgot it already (close).
        """
        manager = manager or getattr(self._pool, "_executor_manager_thread", None)
        procs = mp.active_children()
        for p in procs:
            p.terminate()
        deadline = time.monotonic() + 15.0
        for p in procs:
            p.join(timeout=max(0.0, deadline - time.monotonic()))
        for p in procs:
            if p.is_alive():
                p.kill()
        # the pool's thread closes its wake-up pipe as it ends; at exit, Python writes to that pipe without the lock
        # the thread closes it under, so an exit while the thread ended was a traceback (EBADF) after the one line.
        # shutdown() forgets the thread: it is taken before. The thread also joins the workers as it ends: a worker it
        # reaped while this thread waited for it too looked alive here until the thread noted its exit code (close, a
        # race: test_a_worker_that_cannot_exit_does_not_hold_the_study, once on CI, 2026-12-05)
        self._pool.shutdown(wait=False, cancel_futures=True)
        if manager is not None:
            manager.join(timeout=10.0)

    def close(self) -> None:
        """Let the workers end; one still alive CLOSE_WAIT_S later is stopped as abort stops it: a policy of one's own
        that left a thread running in it kept it from exiting (Python's exit waits for the thread), and the study
        waited for it without end, every cell done and no report written (issue 82, probe 12, N6)."""
        procs = mp.active_children()
        manager = getattr(self._pool, "_executor_manager_thread", None)
        self._pool.shutdown(wait=False)
        deadline = time.monotonic() + CLOSE_WAIT_S
        for p in procs:
            p.join(timeout=max(0.0, deadline - time.monotonic()))
        if any(p.is_alive() for p in procs):
            self.abort(manager)
        else:
            self._pool.shutdown(wait=True)


CLOSE_WAIT_S = 30.0
"""how long a study waits for its workers to exit once its cells are done (LocalBackend.close)"""


def run_remote_cell(cell_fn: CellFn, spec: dict[str, Any], root: str) -> dict[str, Any]:
    """A Ray task: cell_fn(spec, root) on a node (RayBackend)."""
    return cell_fn(spec, root)


class RayBackend:
    """Cells as Ray tasks (num_cpus=1; a worker process runs one cell after another, as the local pool's do) on a
    local instance or a cluster."""

    name = "ray"

    def __init__(self, workers: int, address: str | None,
                 cell_fn: Callable[[dict[str, Any], str], dict[str, Any]]):  # fmt: skip
        import ray

        self._ray = ray
        self.address = address
        kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": False}
        if address is None:
            kwargs["num_cpus"] = workers
        try:  # without --address, a new local instance: never a cluster some other program left running here
            ray.init(address=address or "local", **kwargs)
        except (ConnectionError, ValueError, RuntimeError) as err:
            detail = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            where = f" at {address}" if address else ""
            raise UsageError(f"cannot start or reach Ray{where}: {detail}") from None
        self.slots = max(1, int(ray.cluster_resources().get("CPU", workers)))
        # the cell function travels as an argument, stored once: a study's is a bound method (cells.CellKind.run_cell),
        # which @ray.remote does not take as a task
        self._task = ray.remote(num_cpus=1, max_retries=1)(run_remote_cell)
        self._cell_fn = ray.put(cell_fn)

    def check_cluster(self, root: Path, timeout_s: float = 120.0) -> None:
        """Every alive node of the cluster runs this machine's versions (PINNED) and can write root, or UsageError
        naming the node and the problem (one probe task pinned to each node, before any cell runs)."""
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        from coopsumo.provenance import versions

        nodes = [n for n in self._ray.nodes() if n.get("Alive") and n.get("Resources", {}).get("CPU", 0) > 0]
        probe = self._ray.remote(num_cpus=0, max_retries=0)(node_probe)
        refs = [probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False))
                .remote(str(root)) for n in nodes]  # fmt: skip
        try:
            answers = self._ray.get(refs, timeout=timeout_s)
        except Exception as err:
            raise UsageError(f"a node of the Ray cluster did not answer its probe: {type(err).__name__}") from None
        if (problem := cluster_problem(versions(), [n["NodeManagerAddress"] for n in nodes], answers, root)):
            raise UsageError(problem)

    def submit(self, spec: dict[str, Any], root: Path) -> Any:
        return self._task.remote(self._cell_fn, spec, str(root))

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


PINNED = ("coopsumo", "sumo", "libsumo", "torch", "python")
"""versions every node of a cluster must share with the machine that starts the study"""


def node_probe(root: str) -> dict[str, Any]:
    """What one node of a cluster runs, and whether it can write the study's folder (a file made and removed)."""
    import socket

    from coopsumo.provenance import versions

    probe = Path(root) / f".node-probe-{socket.gethostname()}-{os.getpid()}"
    try:
        probe.write_text("ok")
        probe.unlink()
        problem = None
    except OSError as err:
        problem = err.strerror or type(err).__name__
    return {"versions": versions(), "write_problem": problem}


def cluster_problem(mine: dict[str, str], nodes: Sequence[str], answers: Sequence[dict[str, Any]],
                    root: Path) -> str | None:  # fmt: skip
    """Why the cluster cannot run this study (a node with other versions, a node that cannot write root), or None."""
    for node, answer in zip(nodes, answers, strict=True):
        theirs = answer["versions"]
        for name in PINNED:
            if theirs.get(name) != mine.get(name):
                return (f"--address: node {node} runs {name} {theirs.get(name)}, this machine {mine.get(name)}; "
                        "install the same versions on every node")  # fmt: skip
        if answer["write_problem"]:
            return (f"--out {root}: node {node} cannot write it ({answer['write_problem']}); give a folder every "
                    "node shares")  # fmt: skip
    return None


def add_backend_flags(parser: Any) -> None:
    """--backend local|ray and --address, the same on every study."""
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="local process pool or Ray")
    parser.add_argument("--address", default=None, help="Ray cluster address (default: start a local Ray instance)")


def check_backend(backend: str, address: str | None) -> None:
    """Usage errors before anything is written: --address without Ray, Ray not installed, a cluster that does
    not answer (ray_probe.check_ray_address: within 30 s)."""
    from coopsumo.studies.engine.ray_probe import check_ray_address

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
    from coopsumo.runio import Stop

    raise Stop(signum)  # a KeyboardInterrupt that keeps its signal: exit code 143 (issue 82, probe 8, J17: 130)


@contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM in the main process becomes KeyboardInterrupt (runio.Stop, which names it), so the workers are stopped
    cleanly."""
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


WAITING_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}, no estimate until a cell ends{postfix}]"
"""the progress bar until the first cell of an execute call ends: elapsed time, no estimate of the time left (which
would rest on no cell's time); tqdm's own format, with the estimate, from then on"""
LABEL_CHARS = 32
"""a cell's label on the progress bar: its key, cut in the middle beyond this many characters"""
SHOWN_IN_FLIGHT = 3
"""the progress bar names at most this many cells in flight, then says how many more"""


def cell_label(spec: dict[str, Any]) -> str:
    """A cell's short name on the progress bar: its key (cells/<key>.json), cut in the middle when longer than
    LABEL_CHARS; a training cell whose key does not say so is called one."""
    key = str(spec["key"])
    if len(key) > LABEL_CHARS:
        head = (LABEL_CHARS - 2) // 2
        key = key[:head] + ".." + key[len(key) - (LABEL_CHARS - 2 - head):]
    return key if spec.get("kind") != "train" or key.startswith("train") else f"training {key}"


def in_flight_text(running: Sequence[dict[str, Any]], failed: int) -> str:
    """The progress bar's postfix: the cells running now (the first SHOWN_IN_FLIGHT by label, then how many more)
    and how many failed so far; empty when neither."""
    names = ", ".join(cell_label(spec) for spec in running[:SHOWN_IN_FLIGHT])
    more = f" and {len(running) - SHOWN_IN_FLIGHT} more" if len(running) > SHOWN_IN_FLIGHT else ""
    parts = ([f"running {names}{more}"] if running else []) + ([f"{failed} failed"] if failed else [])
    return "; ".join(parts)


class _Schedule:
    """The cells of one execute call: which wait, which run, which finished, and each record's writing.

    A dead worker breaks the whole pool, so every cell in flight sees BrokenProcessPool; such cells are rerun alone
    ("solo"), where a crash can only be their own, before one is recorded as failed."""

    def __init__(self, specs: Sequence[dict[str, Any]], root: Path, backend: LocalBackend | RayBackend, bar: Any,
                 failed_record: FailedRecord, done_keys: Sequence[str]) -> None:  # fmt: skip
        self.root, self.backend, self.bar, self.failed_record = root, backend, bar, failed_record
        self.todo = list(specs)
        self.pending = {spec["key"] for spec in specs}  # not finished yet in this call
        self.ok_keys: set[str] = set(done_keys)
        self.failed_keys: set[str] = set()
        self.solo: deque[dict[str, Any]] = deque()
        self.solo_running = False
        self.inflight: dict[Any, dict[str, Any]] = {}
        self.crashes: Counter[str] = Counter()
        self.counts = {"ok": 0, "failed": 0}
        self.ended = False  # a cell that ran has ended: the bar may estimate the time left

    def show(self) -> None:
        """Name the cells in flight on the bar (drawn at its next refresh)."""
        self.bar.set_postfix_str(in_flight_text(list(self.inflight.values()), self.counts["failed"]), refresh=False)

    def finish(self, spec: dict[str, Any], record: dict[str, Any]) -> None:
        write_json(cell_path(self.root, spec["key"]), record)
        self.pending.discard(spec["key"])
        (self.ok_keys if record["status"] == "ok" else self.failed_keys).add(spec["key"])
        self.counts[record["status"]] += 1
        self.show()
        self.bar.update(1)

    def startable(self) -> list[dict[str, Any]]:
        """Cells of todo whose dependency is done (a failed dependency fails them at once)."""
        ready = []
        for spec in list(self.todo):
            dep = spec.get("after")
            if dep in self.failed_keys:
                self.todo.remove(spec)
                self.finish(spec, self.failed_record(spec, f"needs cell {dep}, which failed"))
            elif dep is None or dep in self.ok_keys or dep not in self.pending:
                ready.append(spec)
        return ready

    def submit(self) -> None:
        """A solo cell alone once nothing runs; else as many startable cells as the backend has free slots."""
        if self.solo and not self.inflight:
            spec = self.solo.popleft()
            self.inflight[self.backend.submit(spec, self.root)] = spec
            self.solo_running = True
        if self.solo or self.solo_running:
            return
        ready = self.startable()
        if not ready and not self.inflight and self.todo:  # only cells waiting on cells that will never run
            for spec in self.todo:
                self.finish(spec, self.failed_record(spec, f"needs cell {spec.get('after')}, which did not run"))
            self.todo.clear()
        for spec in ready[: max(0, self.backend.slots - len(self.inflight))]:
            self.todo.remove(spec)
            self.inflight[self.backend.submit(spec, self.root)] = spec
        self.show()

    def take(self, handle: Any, outcome: Any) -> None:
        """One finished cell: record it, or queue it to run solo after a broken pool."""
        spec = self.inflight.pop(handle)
        was_solo, self.solo_running = self.solo_running, self.solo_running and bool(self.inflight)
        if isinstance(outcome, BrokenProcessPool):
            self.crashes[spec["key"]] += 1
            if not (was_solo and self.crashes[spec["key"]] >= MAX_CRASHES):
                self.solo.append(spec)
                return
            record = self.failed_record(spec, f"worker process died {MAX_CRASHES} times (BrokenProcessPool)")
        elif isinstance(outcome, BaseException):
            record = self.failed_record(spec, f"{type(outcome).__name__}: {str(outcome).strip()[:300]}")
        else:
            record = outcome
        if record["status"] == "interrupted":
            raise KeyboardInterrupt(f"cell {spec['key']} interrupted")
        if not self.ended:  # from now on the bar has a cell's time to estimate from
            self.ended = True
            self.bar.bar_format = None
        self.finish(spec, record)


def execute(specs: Sequence[dict[str, Any]], root: Path, backend: LocalBackend | RayBackend, total: int,
            done_before: int, progress: bool, failed_record: FailedRecord, desc: str = "cells",
            done_keys: Sequence[str] = ()) -> dict[str, int]:  # fmt: skip
    """Run the cells in the given order (the order is the priority); write each record the moment it arrives.

    total and done_before size the progress bar (cells of the whole study, cells finished before this call);
    done_keys: cells finished ok before this call (a cell's "after" may name one). Returns counts of ok/failed
    cells. On KeyboardInterrupt (Ctrl-C or SIGTERM) the workers are stopped and the interrupt re-raised.
    """
    (root / "cells").mkdir(parents=True, exist_ok=True)
    if isinstance(backend, RayBackend) and backend.address is not None:
        backend.check_cluster(root)
    bar = tqdm(total=total, initial=done_before, desc=desc, unit="cell", file=sys.stderr, disable=not progress,
               mininterval=1.0, smoothing=0.1, bar_format=WAITING_FORMAT)  # fmt: skip
    schedule = _Schedule(specs, root, backend, bar, failed_record, done_keys)
    try:
        while schedule.todo or schedule.solo or schedule.inflight:
            raise_swallowed_stop()  # a Ctrl-C the code it landed in swallowed (during the imports) stops it here
            schedule.submit()
            bar.refresh()  # the elapsed time moves on while long cells run
            for handle, outcome in backend.wait(list(schedule.inflight), timeout=1.0):
                schedule.take(handle, outcome)
    except KeyboardInterrupt:
        bar.close()
        with _signals_ignored():
            backend.abort()
        raise
    bar.close()
    return schedule.counts
