"""One validation layer for the inputs of every command.

A bad value becomes one line naming the flag, the value and the allowed range (exit code 2),
before anything is written. Single values are checked while parsing (`argparse` `type=`
callables: `seed`, `integer(...)`, `number(...)`; argparse names the flag); values that depend
on each other or come as lists are checked after parsing (`check_*`, `number_list`), raising
UsageError with the flag in the message.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from coopsumo.runio import UsageError

SEED_MAX = 2**31 - 1
"""largest seed: SUMO's --seed is a C int"""
MAX_STEPS = 10_000_000
"""largest step count of one run (about 11.6 days of 0.1 s steps, 100 times the paper's run)"""
MAX_SEEDS = 1000
"""largest number of seeds of a study"""
MAX_REPLAY = 1_000_000
"""largest replay memory (transitions; about 0.4 GB)"""
ALPHA_MIN = 0.0
"""the lane-change penalty alpha of eq. (7) is a finite number >= this (the one place the rule lives)"""
RAY_PROBE_TIMEOUT_S = 20.0
"""time a Ray cluster address gets to answer (s); with the socket check, failure comes within 30 s"""


def max_workers() -> int:
    """Largest --workers: four processes per core of this machine."""
    return 4 * (os.cpu_count() or 1)


def _int_range(low: int, high: int | None) -> str:
    return f"an integer from {low} to {high}" if high is not None else f"an integer >= {low}"


def _number_range(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
    hi = "" if high is None else f"{'<' if high_open else '<='} {high:g}"
    return "a finite number" + (f" {lo}" if lo else "") + (" and" if lo and hi else "") + (f" {hi}" if hi else "")


def int_problem(value: int, low: int, high: int | None = None) -> str | None:
    """None when low <= value <= high, else the allowed range in words."""
    return None if low <= value and (high is None or value <= high) else _int_range(low, high)


def number_problem(value: float, low: float | None = None, high: float | None = None,
                   low_open: bool = False, high_open: bool = False) -> str | None:  # fmt: skip
    """None when value is finite and inside the bounds (open or closed), else the allowed range in words."""
    ok = math.isfinite(value)
    ok = ok and (low is None or (value > low if low_open else value >= low))
    ok = ok and (high is None or (value < high if high_open else value <= high))
    return None if ok else _number_range(low, high, low_open, high_open)


# -- argparse type= callables (argparse prefixes "argument --flag:") ------------------------------
def integer(low: int, high: int | None = None, note: str = "") -> Callable[[str], int]:
    """A `type=` for an integer flag in [low, high]; note is added to the range (e.g. its reason)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or int_problem(value, low, high):
            raise argparse.ArgumentTypeError(f"must be {_int_range(low, high)}{note}, got {text!r}")
        return value

    parse.__name__ = "integer"
    return parse


def number(low: float | None = None, high: float | None = None, low_open: bool = False, high_open: bool = False,
           note: str = "") -> Callable[[str], float]:  # fmt: skip
    """A `type=` for a finite float flag inside the bounds."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        problem = number_problem(value, low, high, low_open, high_open)
        if problem:
            raise argparse.ArgumentTypeError(f"must be {problem}{note}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


seed = integer(0, SEED_MAX, " (SUMO's seed range)")
"""`type=` of a --seed flag"""
steps = integer(1, MAX_STEPS)
"""`type=` of a step-count flag"""
seed_count = integer(1, MAX_SEEDS)
"""`type=` of a --seeds (how many) flag"""
alpha = number(ALPHA_MIN)
"""`type=` of an --alpha flag"""


def out_dir(text: str) -> Path:
    """A `type=` for --out: a folder path SUMO can write into. SUMO reads an output file name holding ':' as
    host:port, so such a path (given, or the current folder's) is refused here instead of failing inside SUMO."""
    path = Path(text)
    if not text or ":" in str(path.absolute()):
        raise argparse.ArgumentTypeError(f"must be a folder path without ':' (SUMO reads an output file name with ':' "
                                         f"as host:port), got {str(path.absolute())!r}")  # fmt: skip
    return path


def workers(text: str) -> int:
    """`type=` of a --workers flag: 1 to four per core."""
    return integer(1, max_workers(), f" (4 per core; this machine has {os.cpu_count() or 1})")(text)


# -- checks after parsing (UsageError naming the flag) ---------------------------------------------
def check_int(flag: str, value: int, low: int, high: int | None = None, note: str = "") -> int:
    problem = int_problem(value, low, high)
    if problem:
        raise UsageError(f"{flag} must be {problem}{note}, got {value}")
    return value


def check_number(flag: str, value: float, low: float | None = None, high: float | None = None,
                 low_open: bool = False, high_open: bool = False, note: str = "") -> float:  # fmt: skip
    problem = number_problem(value, low, high, low_open, high_open)
    if problem:
        raise UsageError(f"{flag} must be {problem}{note}, got {value:g}")
    return value


def parse_number(text: str) -> float:
    """'1/8' -> 0.125, '2.5' -> 2.5; ValueError otherwise (also for a zero denominator)."""
    text = text.strip()
    if "/" in text:
        num, den = text.split("/", 1)
        try:
            return float(num) / float(den)
        except ZeroDivisionError:
            raise ValueError(f"division by zero in {text!r}") from None
    return float(text)


def number_list(flag: str, text: str, low: float | None = None, high: float | None = None,
                low_open: bool = False, whole: bool = False, note: str = "") -> tuple[float, ...]:  # fmt: skip
    """A comma-separated list of finite numbers (fractions like 1/8 allowed) inside the bounds, not empty.

    whole: every value must be a whole number; note is added to the range in the message.
    """
    parts = [x for x in text.split(",") if x.strip()]
    kind = "whole numbers" if whole else "numbers"
    try:
        values = tuple(parse_number(x) for x in parts)
    except ValueError:
        values = ()
    problem = next((p for v in values if (p := number_problem(v, low, high, low_open))), None)
    if not values or problem or (whole and any(v != int(v) for v in values)):
        rng = (problem or _number_range(low, high, low_open, False)).replace("a finite number", f"finite {kind}")
        raise UsageError(f"{flag} must be a comma-separated list of {rng}{note}, got {text!r}")
    return values


def alpha_list(flag: str, text: str) -> tuple[float, ...]:
    """A comma-separated list of alphas (--alphas), each a finite number >= ALPHA_MIN."""
    return number_list(flag, text, low=ALPHA_MIN)


def number_name(x: float) -> str:
    """x in a cell key, folder or column name: as :g prints it when that reads back as exactly x (8 -> "8",
    0.125 -> "0.125"), else the shortest text that does (8.000001 -> "8.000001"); distinct values never share one."""
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


def distinct_list(flag: str, text: str, low: float | None = None, low_open: bool = False,
                  note: str = "") -> tuple[float, ...]:  # fmt: skip
    """A study axis: comma-separated finite numbers inside the bounds, no empty item and no value twice (they
    name run folders: number_name); UsageError otherwise."""
    items = text.split(",")
    if any(not x.strip() for x in items):
        raise UsageError(f"{flag} has an empty item in {text!r}; give comma-separated numbers")
    values = number_list(flag, text, low=low, low_open=low_open, note=note)
    names = [number_name(v) for v in values]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise UsageError(f"{flag} lists {', '.join(twice)} more than once in {text!r}")
    return values


def min_t_up_s(dt_s: float) -> float:
    """Smallest accepted T_up (s): one vehicle per simulation step, so the demand never schedules more
    vehicles than the run has steps (its memory stays bounded whatever T_up is asked for)."""
    return dt_s


def t_up_note(dt_s: float) -> str:
    """Why T_up has its lower limit, for messages."""
    limit = min_t_up_s(dt_s)
    return f" s (one vehicle per {limit:g} s simulation step, {3600 / limit:,.0f} veh/h)"


def check_t_up(flag: str, value: float, dt_s: float) -> float:
    """T_up (s) finite and at least one simulation step."""
    return check_number(flag, value, low=min_t_up_s(dt_s), note=t_up_note(dt_s))


def t_up_list(flag: str, text: str, dt_s: float) -> tuple[float, ...]:
    """A list of distinct demands T_up (s), each at least one simulation step."""
    return distinct_list(flag, text, low=min_t_up_s(dt_s), note=t_up_note(dt_s))


def check_accident(start: int, duration: int, steps: int, start_flag: str = "--accident-start",
                   steps_flag: str = "--accident-steps") -> None:  # fmt: skip
    """The accident window starts inside the run (0 .. steps - 1) and has a positive length.

    It may end after the run (the hold probability then has not decayed to 0 when the run ends).
    """
    check_int(start_flag, start, 0, steps - 1, f" (a step of the {steps}-step run)")
    check_int(steps_flag, duration, 1, MAX_STEPS)


# -- Ray cluster addresses ------------------------------------------------------------------------
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
"""HTTP/2 client preface and an empty SETTINGS frame: a gRPC server (Ray's GCS) answers with SETTINGS"""

_RAY_PROBE = """
import logging, sys
import ray
try:
    ray.init(address=sys.argv[1], include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False)
except Exception as err:
    text = str(err).strip()
    print(text.splitlines()[0] if text else type(err).__name__)
    sys.exit(1)
ray.shutdown()
"""


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of 'host:port' or 'ray://host:port'; None for 'auto', 'local' and the like."""
    m = re.fullmatch(r"(?:ray://)?\[?([^\s\[\]]+?)\]?:(\d+)", address.strip())
    return (m.group(1), int(m.group(2))) if m else None


def _answers_http2(host: str, port: int, timeout_s: float) -> str | None:
    """None when host:port accepts a connection and answers like a gRPC server, else why not."""
    if not 0 < port < 65536:
        return f"port {port} is not a TCP port"
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as conn:
            conn.settimeout(timeout_s)
            conn.sendall(_HTTP2_PREFACE)
            head = conn.recv(9)
    except TimeoutError:
        return f"no answer within {timeout_s:g} s"
    except OSError as err:
        return err.strerror or type(err).__name__
    if len(head) < 4 or head[3] != 4:  # frame type 4: SETTINGS
        return "it does not answer like a Ray cluster (no gRPC)"
    return None


def check_ray_address(flag: str, address: str, timeout_s: float | None = None) -> None:
    """A Ray cluster answers at `address`, or UsageError naming it, within about timeout_s (s).

    A quick socket check first (refused, unreachable, silent, not gRPC); then `ray.init` in a child
    process that is killed when it has not connected in time (Ray itself retries for minutes and logs
    each attempt). Its output is discarded.
    """
    timeout = RAY_PROBE_TIMEOUT_S if timeout_s is None else timeout_s
    where = _host_port(address)
    if where is not None:
        why = _answers_http2(where[0], where[1], min(timeout, 5.0))
        if why is not None:
            raise UsageError(f"{flag} {address}: cannot reach a Ray cluster there: {why}")
    proc = subprocess.Popen([sys.executable, "-c", _RAY_PROBE, address], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, start_new_session=True)  # fmt: skip
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the probe and anything it started
        proc.communicate()
        raise UsageError(f"{flag} {address}: no Ray cluster answered within {timeout:g} s") from None
    if proc.returncode != 0:
        detail = out.strip().splitlines()[-1] if out.strip() else f"exit code {proc.returncode}"
        raise UsageError(f"{flag} {address}: cannot connect to a Ray cluster there: {detail}")
