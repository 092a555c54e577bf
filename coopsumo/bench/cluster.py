"""`coopsumo bench --cluster`: a study's cells on a real Ray cluster of one node, then of two (Ray's cluster_utils on
this machine, one CPU each), beside the local backend with one and two workers: the scaling from one node to two."""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

CLUSTER_STUDY = ("scenario1", "--regime-map", "--t-up", "2,1.5,1", "--seeds", "2")
"""the study of the cluster measurement: `keep` at 3 demands x 2 accident lengths x 2 seeds, 12 cells"""
CLUSTER_QUICK = ("scenario1", "--regime-map", "--t-up", "2", "--seeds", "1")
"""--quick: 2 cells"""


class ClusterBenchError(RuntimeError):
    """A study of the cluster bench failed, or the backends' records disagree."""


def bench_cluster(study_args: tuple[str, ...], steps: int, warm_up: bool = True) -> dict[str, float]:
    """Wall time (s) of a study's cells (each `steps` long) on the local backend with 1 and 2 workers and on
    a Ray cluster of 1 and 2 nodes of one CPU each, started on this machine with Ray's cluster_utils (the study
    connects with --backend ray --address as it would to a remote cluster). Every run must give the same runs.csv."""
    import subprocess

    from ray.cluster_utils import Cluster

    def study(out: Path, *backend: str) -> float:
        cmd = [sys.executable, "-m", "coopsumo", *study_args, "--steps", str(steps), "--quiet", "--out", str(out),
               *backend]  # fmt: skip
        start = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if res.returncode != 0:  # its lines after the study's first one, or none (Ray ended it: Ray's logs say why)
            said = (" / ".join(res.stderr.strip().splitlines()[1:][-3:])
                    or "no line of its own (Ray's logs in /tmp/ray/session_latest/logs may say why)")
            raise ClusterBenchError(f"`{' '.join(cmd[1:])}` ended with exit code {res.returncode}: {said}")
        return time.perf_counter() - start

    times: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        # a first study pays for cold caches (imports, the network, SUMO's files): one short one, not timed
        if warm_up:
            warm = [*CLUSTER_QUICK, "--steps", "100", "--quiet", "--out", str(Path(tmp) / "warm-up")]
            subprocess.run([sys.executable, "-m", "coopsumo", *warm], capture_output=True, check=False)
        for workers in (1, 2):
            times[f"local, {workers} worker{'s' if workers > 1 else ''}"] = study(
                Path(tmp) / f"local{workers}", "--workers", str(workers))  # fmt: skip
        for nodes in (1, 2):
            cluster = Cluster(initialize_head=True, connect=False,
                              head_node_args={"num_cpus": 1, "include_dashboard": False})  # fmt: skip
            try:
                for _ in range(nodes - 1):
                    cluster.add_node(num_cpus=1)
                cluster.wait_for_nodes()
                times[f"ray, {nodes} node{'s' if nodes > 1 else ''}"] = study(
                    Path(tmp) / f"ray{nodes}", "--backend", "ray", "--address", cluster.address)  # fmt: skip
            finally:
                cluster.shutdown()
        runs = {p.parent.name: p.read_text() for p in Path(tmp).glob("*/runs.csv") if p.parent.name != "warm-up"}
        if len(set(runs.values())) != 1:
            raise ClusterBenchError(f"the backends disagree: runs.csv differs between {sorted(runs)}")
    return times


def cluster_lines(quick: bool) -> int:
    """bench --cluster's lines: the study, each backend's wall time, the scaling from one node to two; the exit code
    (1 with one line when a study failed or the backends disagree)."""
    cell_steps, study = (100, CLUSTER_QUICK) if quick else (3000, CLUSTER_STUDY)
    print(f"coopsumo bench --cluster: {' '.join(study)}, {cell_steps} steps a cell", flush=True)
    try:
        times = bench_cluster(study, cell_steps, warm_up=not quick)
    except ClusterBenchError as err:
        print(f"coopsumo bench: error: {err}", file=sys.stderr)
        return 1
    for name, wall in times.items():
        print(f"  {name:16s}: {wall:6.1f} s", flush=True)
    print(f"cluster scaling {times['ray, 1 node'] / times['ray, 2 nodes']:.2f}  (wall time on 1 node / on 2 nodes "
          f"of one CPU each; local backend {times['local, 1 worker'] / times['local, 2 workers']:.2f} from 1 to "
          "2 workers; the same runs.csv everywhere)", flush=True)  # fmt: skip
    return 0
