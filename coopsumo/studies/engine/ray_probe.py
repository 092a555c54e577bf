"""Whether a Ray cluster answers at an address (`--address`), asked before a study starts: a socket check (refused,
unreachable, silent, not gRPC), then `ray.init` in a child process that is killed when it has not connected in time
(Ray itself retries for minutes and logs each attempt). Apart from the list and number checks of validation.py: only
the runner asks it."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys

from coopsumo.errors import UsageError

RAY_PROBE_TIMEOUT_S = 20.0
"""time a Ray cluster address gets to answer (s); with the socket check, failure comes within 30 s"""

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
