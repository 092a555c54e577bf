"""Shared helpers for the highway-world tests (physics, observation, reward, policies, SUMO runs).

Pure tests build hand-made vehicle layouts with `layout`; SUMO tests use `sim_config`.
libsumo allows one SUMO per process: in-process SUMO tests open one World at a time
(the context manager closes SUMO), longer sweeps run the CLI in subprocesses.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from file_progress import pytest_addoption, pytest_configure  # noqa: F401  (make test's --file-progress)

from coopsumo.config import AccidentConfig, ControlConfig, DemandConfig, RoadConfig, SimConfig
from coopsumo.sim import physics
from coopsumo.sim.observation import Observation

REPO = Path(__file__).resolve().parent.parent
TIMING_KEYS = frozenset({"wall_seconds", "steps_per_second", "sumo_step_share"})
"""the fields of a run's summary.json that measure the machine, not the run"""
# One OpenMP (torch) thread in the test processes and the commands they start, set before torch is imported: two
# pytest-xdist workers share two cores, and a second torch thread per worker only spins (a test of 200 updates took
# 68 s instead of 1 while the other core was busy). The commands decide and train on one thread already.
os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture
def ctrl() -> ControlConfig:
    """The controller configuration with the paper's collision-check values (a1=2, a2=0.5, v_cc=1, L=4)."""
    cfg = ControlConfig()
    assert (cfg.a1, cfg.a2_s, cfg.v_cc_mps, cfg.car_length_m) == (2.0, 0.5, 1.0, 4.0)
    return cfg


def make_observation(
    lane: list[int],
    pos: list[float],
    speed: list[float],
    v_exp: list[float],
    n_lanes: int = 3,
    other_lane: list[int] | None = None,
    car_length_m: float = 4.0,
) -> Observation:
    """An Observation of a hand-made layout, with neighbours computed by physics (grids left empty)."""
    lane_a = np.asarray(lane, np.int64)
    pos_a = np.asarray(pos, np.float64)
    speed_a = np.asarray(speed, np.float64)
    other = np.full(len(lane_a), -1, np.int64) if other_lane is None else np.asarray(other_lane, np.int64)
    occ = physics.occupancy(lane_a, pos_a, other)
    around = physics.neighbours(occ, pos_a, speed_a, physics.side_lanes(lane_a), n_lanes, car_length_m)
    n = len(lane_a)
    return Observation(
        nums=np.arange(n, dtype=np.int64),
        grids=np.zeros((n, 3, 3, 20), np.uint8),
        speed_err=np.zeros((n, 3), np.float32),
        lane=lane_a,
        pos=pos_a,
        speed=speed_a,
        v_exp=np.asarray(v_exp, np.float64),
        busy=other >= 0,
        around=around,
        n_lanes=n_lanes,
        feasible=physics.feasible_actions(around, other >= 0, speed_a, ControlConfig()),
    )


@pytest.fixture(autouse=True)
def _ctrl_c_reaches_commands() -> None:
    """Commands a test starts get Ctrl-C as from a terminal. An ignored SIGINT stays ignored in every child (exec
    keeps SIG_IGN, and Python then installs no KeyboardInterrupt handler), and the test worker can be left with it
    ignored: in a full run, simulate and train started by later tests then ran through the tests' Ctrl-C."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def observation_of() -> Callable[..., Observation]:
    return make_observation


def sim_config(
    lanes: int = 3,
    t_up_s: float = 2.0,
    steps: int = 1000,
    seed: int = 0,
    policy: str = "keep",
    accident: AccidentConfig | None = None,
) -> SimConfig:
    return SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=t_up_s),
        accident=accident or AccidentConfig(),
        steps=steps,
        seed=seed,
        policy=policy,
    )


@pytest.fixture(scope="session")
def ray_lock(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The file every test process of one `make test` locks while it runs Ray (under xdist each process's temporary
    folder is a child of one run folder)."""
    base = tmp_path_factory.getbasetemp()
    return (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "ray.lock"


@contextmanager
def one_ray_at_a_time(lock: Path) -> Iterator[None]:
    """Ray instances started at once on one machine can draw the same port for two of their parts (Ray issue 18053,
    about 1% of starts): a node then fails, and a study's process ended with exit code 1 and no line of its own (a CI
    run's `bench --cluster` while another test process started Ray). The tests that start Ray run one at a time."""
    with lock.open("a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@pytest.fixture
def ray_alone(ray_lock: Path) -> Iterator[None]:
    """A test that starts Ray holds the lock the other test processes' Ray tests wait for."""
    with one_ray_at_a_time(ray_lock):
        yield


@pytest.fixture(scope="session")
def make_sim_config() -> Callable[..., SimConfig]:
    return sim_config


def run_cli(args: list[str], timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    """`python -m coopsumo.simulate ARGS` in a subprocess (its own SUMO)."""
    return subprocess.run(
        [sys.executable, "-m", "coopsumo.simulate", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
        check=False,
    )


@pytest.fixture(scope="session")
def simulate_cli() -> Callable[..., subprocess.CompletedProcess[str]]:
    return run_cli


def start_cli(args: list[str]) -> subprocess.Popen[str]:
    """Start `python -m coopsumo.simulate ARGS` without waiting (for runs in parallel)."""
    return subprocess.Popen(
        [sys.executable, "-m", "coopsumo.simulate", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )


@pytest.fixture(scope="session")
def parallel_cli() -> Callable[[list[list[str]], int], list[tuple[int, str, str]]]:
    """Run several CLI invocations, at most `workers` at a time; returns (returncode, stdout, stderr) each."""

    def run_all(jobs: list[list[str]], workers: int = 2) -> list[tuple[int, str, str]]:
        results: list[Any] = [None] * len(jobs)
        running: list[tuple[int, subprocess.Popen[str]]] = []
        queue = list(enumerate(jobs))
        while queue or running:
            while queue and len(running) < workers:
                i, args = queue.pop(0)
                running.append((i, start_cli(args)))
            i, proc = running.pop(0)
            out, err = proc.communicate(timeout=600)
            results[i] = (proc.returncode, out, err)
        return results

    return run_all


@pytest.fixture(scope="session")
def display_or_none() -> Iterator[str | None]:
    """An X display for sumo-gui: a private Xvfb server when Xvfb is installed (started once per session),
    else the user's DISPLAY, else None."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        yield os.environ.get("DISPLAY") or None
        return
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(write_fd), "-screen", "0", "1600x900x24", "-nolisten", "tcp"],
                            pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        number = pipe.readline().strip()  # Xvfb writes its display number once it accepts clients
    try:
        if not number:
            pytest.fail(f"Xvfb ({xvfb}) did not start")
        yield f":{number}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.fixture(scope="session")
def gui_display(display_or_none: str | None) -> str:
    """The display for sumo-gui tests; skips them, saying why, when there is none."""
    if display_or_none is None:
        pytest.skip("sumo-gui needs a display: DISPLAY is not set and Xvfb is not installed (apt-get install -y xvfb)")
    return display_or_none


def env_with_display(display: str | None) -> dict[str, str]:
    """This process's environment with DISPLAY set to display (removed when None)."""
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    if display is not None:
        env["DISPLAY"] = display
    return env


class InlineBackend:
    """A study backend that runs each cell in this process, one at a time, with cell_fn(spec, root) -> record
    (for tests whose cells run no SUMO: a faked training, or a cell recorded failed at once)."""

    name = "inline"
    slots = 1

    def __init__(self, cell_fn: Callable[[dict[str, Any], str], dict[str, Any]]) -> None:
        self._cell_fn = cell_fn
        self._done: list[tuple[object, dict[str, Any]]] = []

    def submit(self, spec: dict[str, Any], root: Path) -> object:
        handle = object()
        self._done.append((handle, self._cell_fn(spec, str(root))))
        return handle

    def wait(self, handles: list[object], timeout: float) -> list[tuple[object, dict[str, Any]]]:
        done, self._done = self._done, []
        return done

    def abort(self) -> None:
        pass

    def close(self) -> None:
        pass


def committed_report_pages() -> list[Path]:
    """results/<study>/report.md of every committed study (git's index; without git, every one on disk): a report
    made locally and not committed is not one the README must link."""
    try:
        out = subprocess.run(["git", "ls-files", "results/*/report.md"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return sorted((REPO / "results").glob("*/report.md"))
    return sorted(REPO / line for line in out.splitlines() if len(Path(line).parts) == 3)


NUMBER = r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
REL_TOLERANCE = 1e-9
"""how far a number in a redrawn record may be from the committed one: fits and bootstraps go through numpy's BLAS,
whose last bits differ between processors (docs/run-folders.md, "Exact across machines")"""


def text_difference(committed: str, redrawn: str, rel: float = REL_TOLERANCE) -> str | None:
    """Where two texts differ beyond the last bits of their numbers, or None: the text between numbers must match
    exactly, integers exactly, and each other number to a relative `rel` (an absolute 1e-12 near zero)."""
    import re

    a_parts, b_parts = re.split(f"({NUMBER})", committed), re.split(f"({NUMBER})", redrawn)
    if len(a_parts) != len(b_parts):
        return "the texts hold different numbers of numbers"
    for i, (a, b) in enumerate(zip(a_parts, b_parts, strict=True)):
        if a == b:
            continue
        line = committed[: sum(len(p) for p in a_parts[:i])].count("\n") + 1
        if i % 2 == 0 or not any(c in a + b for c in ".eE"):
            return f"line {line}: {a[:40]!r} != {b[:40]!r}"
        x, y = float(a), float(b)
        if abs(x - y) > max(rel * max(abs(x), abs(y)), 1e-12):
            return f"line {line}: {a} != {b}"
    return None


def main_here(main: Callable[[list[str]], int], argv: list[str],
              capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:  # fmt: skip
    """A command's main(argv) in this process, for refusals made before any simulation (the one-line refusal of a
    command run as a process: tests/test_bad_inputs.py), or a rerun of a study the test ran as a process (capfd then,
    for its workers' output too): its exit code (argparse's SystemExit too), stdout, stderr."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def assert_refused_in_one_line(code: int, err: str, out: Path, fragment: str = "") -> None:
    """Exit code 2, one line on stderr holding fragment, no traceback, nothing written at out."""
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in err, err
    assert not out.exists()


def interrupted_at_step_20(cfg: Any, out: Path) -> Path:
    """A training of cfg (a TrainConfig checkpointing every 20 steps) run in the new folder out as train leaves it
    when killed after its checkpoint of step 20 (its marker, config.json, its log on to the end); returns the path
    of that step-20 checkpoint, kept beside the last one (step20.pt) for the caller to put in place."""
    from coopsumo.agents.train import Trainer
    from coopsumo.run_dirs import mark_run_dir

    out.mkdir()
    mark_run_dir(out, "train", finished=False)
    trainer = Trainer(cfg, out, progress=False)
    save = trainer.save_checkpoint

    def save_and_keep_step_20() -> None:
        save()
        if trainer.step == 20:
            shutil.copy(out / "checkpoint.pt", out / "step20.pt")

    trainer.save_checkpoint = save_and_keep_step_20  # type: ignore[method-assign]
    trainer.run()
    return out / "step20.pt"


MADE_BY = "## Reports made by an earlier default learner"
"""results/README.md's table: | `folder/` | `variant` | commit | ... |, one row per report its learner made"""


def made_by(readme: Path = REPO / "results" / "README.md") -> dict[str, tuple[str, str]]:
    """results/README.md's reports made by an earlier default learner: folder name -> (variant, commit)."""
    text = readme.read_text()
    if MADE_BY not in text:
        return {}
    rows = text.split(MADE_BY, 1)[1].split("\n## ", 1)[0]
    found = re.findall(r"^\| `([\w/]+?)/?` \| `(\w+)` \| `?([0-9a-f]{7,40})`? \|", rows, flags=re.MULTILINE)
    return {folder: (variant, commit) for folder, variant, commit in found}


SLOWEST_FIRST = ("test_early_interrupts.py", "test_scenario2.py", "test_scenario1.py", "test_cluster.py",
                 "test_protocol.py", "test_train.py", "test_docs.py", "test_scenario2_full.py", "test_interrupts.py",
                 "test_faults.py", "test_reused_models.py", "test_faults_scenario1.py", "test_scenario2_merge.py",
                 "test_runner.py", "test_replication.py", "test_conditioned.py",
                 "test_selection.py", "test_update_worker.py", "test_extending.py", "test_sumo_tools.py",
                 "test_world_sumo.py", "test_bench_group.py", "test_mobil.py", "test_record_checks.py",
                 "test_study_commands.py", "test_envs.py", "test_bad_inputs.py", "test_history.py", "test_group.py")
"""the files that take longest (make test's --durations), scheduled first: `make test` runs files on 2 processes
(xdist's loadfile, in collection order with --no-loadscope-reorder), and a long file started last kept one process
busy alone at the end (a scheduling hint only: each file's tests keep their order, and no test depends on another
file's)"""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the order within a file kept
