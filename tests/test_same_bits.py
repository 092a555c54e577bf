"""The world gives the same bits with or without AVX-512: its one transcendental function, the exponential of
Newell's bound, is the C library's (physics.exp), not numpy's, whose vector path on AVX-512 CPUs differs in the
last bit for about 5% of arguments (measured: a dense greedy run through the accident made 2,251 lane changes
there, 2,381 elsewhere)."""

from __future__ import annotations

import ast
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import TIMING_KEYS

from coopsumo.config import ControlConfig
from coopsumo.sim import physics

PACKAGE = Path(physics.__file__).resolve().parent.parent
DISPATCHED = {"exp", "exp2", "expm1", "log", "log2", "log10", "log1p", "power", "float_power", "sin", "cos", "tan",
              "arcsin", "arccos", "arctan", "arctan2", "sinh", "cosh", "tanh", "arcsinh", "arccosh", "arctanh",
              "cbrt", "hypot"}  # fmt: skip
"""numpy functions whose float64 results may depend on the CPU's vector extensions (SVML on AVX-512)"""
WORLD = ["sim", "agents/mobil.py", "agents/policies.py", "agents/decisions.py", "agents/dqn.py", "agents/dqn_policy.py"]
"""the code that moves vehicles: the world, the hand-made policies and a model's decisions"""


def test_exp_is_the_c_librarys_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-40.0, 2.0, 20_000), np.linspace(-1.0, 0.0, 5_001), [0.0, -0.0, 1e-300]])
    got = physics.exp(x)
    assert got.dtype == np.float64 and got.shape == x.shape
    assert all(g == math.exp(v) for g, v in zip(got.tolist(), x.tolist(), strict=True))
    assert physics.exp(np.float64(0.5)).shape == () and physics.exp(np.ones((2, 3))).shape == (2, 3)
    edge = physics.exp(np.array([-np.inf, np.inf, 800.0, -800.0, np.nan]))
    assert edge[0] == 0.0 and edge[1] == np.inf and edge[2] == np.inf and edge[3] == 0.0 and np.isnan(edge[4])


def test_newell_speed_uses_it() -> None:
    cfg = ControlConfig()
    rng = np.random.default_rng(1)
    gap, v_exp = rng.uniform(0.0, 120.0, 5_000), rng.uniform(11.0, 31.0, 5_000)
    got = physics.newell_speed(gap, v_exp, cfg)
    c, d = cfg.newell_c_per_s, cfg.newell_d
    want = [max(v * (1.0 - math.exp(-c * g / v - d)), 0.0) for g, v in zip(gap, v_exp, strict=True)]
    assert got.tolist() == want


def _dispatched_calls(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    return [f"{path.name}:{node.lineno} np.{node.attr}" for node in ast.walk(tree)
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "np"
            and node.attr in DISPATCHED]  # fmt: skip


def test_the_world_calls_no_cpu_dependent_numpy_function() -> None:
    """(torch's log1p of a conditioned network's alpha gave the same bits with AVX2 and AVX-512 on 200,001 alphas.)"""
    files = [p for entry in WORLD for p in sorted((PACKAGE / entry).rglob("*.py"))]
    assert len(files) > 5
    found = [hit for path in files for hit in _dispatched_calls(path)]
    assert not found, "use physics.exp (the C library's), not numpy's: " + ", ".join(found)


def test_the_scan_sees_a_numpy_exp(tmp_path: Path) -> None:
    """The check above could fail."""
    module = tmp_path / "m.py"
    module.write_text("import numpy as np\n\ny = np.exp(1.0) + np.sqrt(2.0)\n")
    assert _dispatched_calls(module) == ["m.py:3 np.exp"]


@pytest.mark.parametrize("shape", [(0,), (1,), (7, 3)])
def test_exp_keeps_shapes(shape: tuple[int, ...]) -> None:
    x = np.full(shape, -0.25)
    assert physics.exp(x).shape == shape


@pytest.mark.sumo
def test_a_dense_run_is_the_same_with_numpys_avx512_paths_off(tmp_path: Path) -> None:
    """End to end: 3,000 steps of `greedy` at T_up 1 s into the accident repeat bit for bit with numpy's AVX-512
    paths switched off. (With np.exp in the Newell bound, on an AVX-512 machine, the mean speed differed by then:
    13.89070 against 13.89055 m/s.) Without AVX-512 both runs take the same paths anyway."""
    args = ["--scenario", "accident", "--t-up", "1", "--policy", "greedy", "--steps", "3000", "--seed", "3",
            "--accident-start", "2000", "--accident-steps", "10000", "--quiet"]  # fmt: skip
    off = {**os.environ, "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR AVX512F AVX512_SKX"}
    summaries = []
    for name, env in (("on", dict(os.environ)), ("off", off)):
        cmd = [sys.executable, "-m", "coopsumo", "simulate", *args, "--out", str(tmp_path / name)]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        assert proc.returncode == 0, proc.stderr[-2000:]
        summary = json.loads((tmp_path / name / "summary.json").read_text())
        summaries.append({k: v for k, v in summary.items() if k not in TIMING_KEYS})
    assert summaries[0]["lane_changes"] > 100  # dense enough to diverge
    assert summaries[0] == summaries[1]
    loops = [(tmp_path / name / "detectors.xml").read_text().split("-->", 1)[1] for name in ("on", "off")]
    assert "<interval" in loops[0] and loops[0] == loops[1]  # every loop's counts, after the header's date
