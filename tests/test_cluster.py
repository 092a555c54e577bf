"""A study on a real multi-node Ray cluster: two Ray nodes on this machine (Ray's own ray.cluster_utils.Cluster),
the study connecting with --backend ray --address as it would to a remote cluster. Its records equal the local
backend's; a node removed in the middle of a study loses nothing; a folder a node cannot write is refused."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import one_ray_at_a_time

pytestmark = pytest.mark.sumo
REPO = Path(__file__).resolve().parent.parent
STUDY = ["-m", "coopsumo", "scenario1", "--regime-map", "--t-up", "2,1", "--seeds", "1", "--steps", "300", "--quiet"]
"""`keep` at 2 demands x 2 accident lengths x 1 seed: 4 short cells, two a node (a Ray task starts a fresh worker
process, so the node is removed while cells run on it or wait for it)"""


@pytest.fixture(scope="module", autouse=True)
def _ray_alone(ray_lock: Path) -> Iterator[None]:
    """The module's clusters start while no other test process runs Ray (conftest.one_ray_at_a_time)."""
    with one_ray_at_a_time(ray_lock):
        yield


@pytest.fixture(scope="module")
def cluster() -> Iterator[tuple[Any, Any]]:
    """A head node and a worker node, one CPU each, shared by the module's tests (a test that removes the worker
    node adds another)."""
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    c = Cluster(initialize_head=True, connect=False, head_node_args={"num_cpus": 1, "include_dashboard": False})
    worker = c.add_node(num_cpus=1)
    c.wait_for_nodes()
    try:
        yield c, worker
    finally:
        c.shutdown()


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "DISPLAY"}


def _run(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *STUDY, *extra, "--out", str(out)], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=600, check=False)  # fmt: skip


def test_the_cluster_bench_runs_one_study_on_every_backend_with_the_same_records() -> None:
    """`coopsumo bench --cluster` (docs/performance.md): the figures are printed; what is checked is that all four
    backends ran and that bench.cluster found their runs.csv equal (it fails otherwise). It runs before the module's
    cluster is started: it starts its own."""
    pytest.importorskip("ray")
    res = subprocess.run([sys.executable, "-m", "coopsumo", "bench", "--cluster", "--quick"], cwd=REPO, env=_env(),
                         capture_output=True, text=True, timeout=900, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    for line in ("local, 1 worker", "local, 2 workers", "ray, 1 node", "ray, 2 nodes", "cluster scaling"):
        assert line in res.stdout, res.stdout


def test_a_study_on_two_nodes_equals_the_local_one_and_loses_nothing_with_a_node(
    tmp_path: Path, cluster: tuple[Any, Any]
) -> None:
    """The worker node removed while the study runs: its cells are retried on the other node (or, if recorded as
    failed, redone by the rerun); nothing recorded is lost and the records equal the local backend's. (A whole
    study on the two nodes equal to the local one, without a loss, is the cluster bench test's "ray, 2 nodes".)"""
    c, worker = cluster
    local = tmp_path / "local"
    res = _run(local, "--workers", "2")
    assert res.returncode == 0, res.stderr[-2000:]
    expected = (local / "runs.csv").read_text()

    lost = tmp_path / "lost"
    proc = subprocess.Popen([sys.executable, *STUDY, "--backend", "ray", "--address", c.address, "--out",
                             str(lost)], cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    deadline = time.monotonic() + 300
    while not any((lost / "cells").glob("*.json")):
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        assert time.monotonic() < deadline
        time.sleep(0.05)
    recorded = {p.name: p.read_text() for p in (lost / "cells").glob("*.json")}
    c.remove_node(worker)
    try:
        _, err = proc.communicate(timeout=600)
    finally:  # the module's other tests get two nodes again
        c.add_node(num_cpus=1)
        c.wait_for_nodes()
    for name, text in recorded.items():  # what was recorded before the loss stays as it was
        assert (lost / "cells" / name).read_text() == text, name
    if proc.returncode != 0:  # cells lost with the node are recorded as failed: the rerun redoes them
        assert "failed" in err, err[-2000:]
        res = _run(lost, "--backend", "ray", "--address", c.address)
        assert res.returncode == 0, res.stderr[-2000:]
    assert (lost / "runs.csv").read_text() == expected
    records = [json.loads(p.read_text()) for p in (lost / "cells").glob("*.json")]
    assert len(records) == 4 and all(r["status"] == "ok" for r in records)


def test_a_node_that_cannot_write_the_folder_is_refused_in_one_line() -> None:
    from coopsumo.provenance import versions
    from coopsumo.studies.engine.runner import cluster_problem

    mine = versions()
    ok = {"versions": dict(mine), "write_problem": None}
    assert cluster_problem(mine, ["10.0.0.1", "10.0.0.2"], [ok, ok], Path("/shared/out")) is None
    unwritable = {"versions": dict(mine), "write_problem": "Read-only file system"}
    text = cluster_problem(mine, ["10.0.0.1", "10.0.0.2"], [ok, unwritable], Path("/shared/out"))
    assert text is not None and "--out /shared/out: node 10.0.0.2 cannot write it (Read-only file system)" in text
    other = {"versions": {**mine, "coopsumo": "0.0.1"}, "write_problem": None}
    text = cluster_problem(mine, ["10.0.0.1"], [other], Path("/shared/out"))
    assert text is not None and text.startswith("--address: node 10.0.0.1 runs coopsumo 0.0.1, this machine ")


SCENARIO2 = ["-m", "coopsumo", "scenario2", "--profile", "paper", "--lanes", "2", "--t-up", "2", "--alphas", "0,8",
             "--seeds", "1", "--eval-seeds", "1", "--steps", "300", "--eval-steps", "1200", "--mobil-p", "0",
             "--bootstrap", "50", "--quiet"]  # fmt: skip
"""scenario II's paper profile at a tiny size: a model per alpha (300 steps each) for the one lane count, keep, greedy
and MOBIL p = 0 on one evaluation seed: 5 cells"""


def test_the_paper_profile_of_scenario2_runs_on_two_nodes_as_locally(tmp_path: Path,
                                                                    cluster: tuple[Any, Any]) -> None:  # fmt: skip
    """The paper profile (a Ray cluster's, issue 65) at a tiny size on the two-node cluster: the network trained
    there (each run has its own model store) and every cell's measures equal to the local backend's."""
    import pandas as pd

    c, _ = cluster
    outs = {"local": tmp_path / "a" / "local", "ray": tmp_path / "b" / "ray"}
    for name, extra in (("local", ["--workers", "2"]), ("ray", ["--backend", "ray", "--address", c.address])):
        res = subprocess.run([sys.executable, *SCENARIO2, *extra, "--out", str(outs[name])], cwd=REPO, env=_env(),
                             capture_output=True, text=True, timeout=600, check=False)  # fmt: skip
        assert res.returncode == 0, res.stderr[-2000:]
    columns = ["key", "policy", "status", "mean_speed_mps", "full_road_speed_mps", "lane_changes", "departed",
               "collisions", "train_updates"]  # fmt: skip
    local, ray = (pd.read_csv(outs[k] / "runs.csv")[columns] for k in ("local", "ray"))
    assert len(local) == 5 and (local["status"] == "ok").all()
    pd.testing.assert_frame_equal(ray, local)
    assert (outs["ray"] / "gate.csv").read_text() == (outs["local"] / "gate.csv").read_text()
    assert (tmp_path / "b" / "models").is_dir() and any((tmp_path / "b" / "models").iterdir())


def test_without_address_ray_starts_its_own_instance_beside_a_running_cluster(cluster: tuple[Any, Any]) -> None:
    """Ray's `init()` without an address joins the last cluster started on the machine (here the module's, 2 CPUs);
    `--backend ray` without `--address` starts its own with --workers CPUs instead (CI failed when another test's
    cluster ran beside a local Ray study)."""
    code = ("from coopsumo.studies.engine import runner\n"
            "b = runner.make_backend('ray', 3, None, lambda spec, root: spec)\n"
            "print('slots', b.slots)\n")  # fmt: skip
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=_env(), capture_output=True, text=True,
                         timeout=300, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert "slots 3" in res.stdout


def test_a_failed_study_of_the_cluster_bench_is_one_line_and_exit_code_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A study of `bench --cluster` that failed (a CI run: exit code 1, no line of its own) is named in one line with
    its exit code, not a traceback."""
    from coopsumo.bench import cluster as bench

    def failing(*_args: Any, **_kw: Any) -> dict[str, float]:
        raise bench.ClusterBenchError("`-m coopsumo scenario1 --backend ray` ended with exit code 1: no line")

    monkeypatch.setattr(bench, "bench_cluster", failing)
    assert bench.cluster_lines(quick=True) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("coopsumo bench: error: `-m coopsumo scenario1")
    assert "exit code 1" in err
