"""coopsumo: cooperative lane changing via deep RL, reproduced on Eclipse SUMO."""

__version__ = "0.1.0"
