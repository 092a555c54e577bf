"""Gymnasium and PettingZoo environments on the coopsumo World.

Importing this package registers the Gymnasium id `coopsumo/Highway-v0` (HighwayEnv); it never
starts SUMO (that happens in reset()). HighwayParallelEnv is the PettingZoo ParallelEnv in which
every vehicle is an agent. Both must be close()d: libsumo allows one SUMO per process.
"""

from __future__ import annotations

import gymnasium

from coopsumo.envs.highway_env import HighwayEnv
from coopsumo.envs.parallel_env import HighwayParallelEnv

ENV_ID = "coopsumo/Highway-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="coopsumo.envs.highway_env:HighwayEnv")

__all__ = ["ENV_ID", "HighwayEnv", "HighwayParallelEnv"]
