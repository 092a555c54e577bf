"""The one part pyproject.toml cannot declare stably: the C extension of the world's per-step loops
(coopsumo/sim/kernels.c, used by coopsumo/sim/fast.py); building it needs a C compiler."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "coopsumo.sim._kernels",
            ["coopsumo/sim/kernels.c"],
            extra_compile_args=["-O2", "-ffp-contract=off"],  # no fused multiply-add: bit for bit the numpy definitions
        )
    ]
)
