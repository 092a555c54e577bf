"""Scenario II's plan: the sweep's profiles (lanes, loads or T_up, alphas, MOBIL politeness, seeds, steps), the
configuration of every cell and their keys. No SUMO here; scenario2.py runs the plan.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from typing import Any

from coopsumo.config import (
    DQN_PRESETS,
    PAPER_ALPHAS,
    DemandConfig,
    DQNConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.validation import number_name

QUICK_ALPHAS = (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 8.0)
"""the paper's small values and where the default learner's lane changes fall to none (results/learning)"""
NOMINAL_CAPACITY_VEH_H_PER_LANE = 1800.0
"""capacity used to place the T_up grid: load 1 means T_up = 3600 / (lanes * 1800) s (near capacity)"""
POLICIES = ("dqn", "mobil")
"""the two kinds of cell: a DQN trained and evaluated per alpha, MOBIL evaluated per politeness p"""
EVAL_SEED_BASE = 2000
"""evaluation seeds are EVAL_SEED_BASE + 1, + 2, ...: demands no training of the sweep saw (training seeds are 1, 2,
...; validation seeds 900,000 and above)"""


# -- the plan ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Profile:
    """Grid and step counts of one sweep."""

    name: str
    lanes: tuple[int, ...]
    loads: tuple[float, ...]
    """inflow as a share of lanes x 1,800 veh/h; T_up = 3600 / (load x lanes x 1800) s, 2 decimals"""
    alphas: tuple[float, ...]
    seeds: tuple[int, ...]
    """training seeds: one model per seed (per condition and alpha)"""
    train_steps: int
    """training steps (0.1 s) per cell"""
    eval_steps: int
    """greedy evaluation steps per cell"""
    t_up_s: tuple[float, ...] = ()
    """if set, this fixed T_up list (s) replaces the load grid for every lane count"""
    policies: tuple[str, ...] = ("dqn",)
    """"dqn" (train and evaluate per alpha) and/or "mobil" (evaluate MOBIL per politeness p, no training)"""
    mobil_ps: tuple[float, ...] = (0.0, 0.25, 0.5, 1.0)
    """MOBIL politeness grid, used when "mobil" is in policies"""
    preset: str = "default"
    """the learner preset of every DQN cell (config.DQN_PRESETS)"""
    conditioned: bool = False
    """one alpha-conditioned training per condition and seed (not per alpha), evaluated at every alpha"""
    eval_seeds: tuple[int, ...] = (EVAL_SEED_BASE + 1,)
    """evaluation seeds: every model (and MOBIL) is evaluated greedily on each of them; none is a training seed"""

    def conditions(self) -> list[tuple[int, float, float]]:
        """(lanes, T_up s, load) of every condition, by lanes then decreasing T_up."""
        out = []
        for n in self.lanes:
            if self.t_up_s:
                pairs = [(t, load_of(n, t)) for t in self.t_up_s]
            else:
                pairs = [(t_up_for(n, load), load) for load in self.loads]
            out += [(n, t, load) for t, load in sorted(pairs, reverse=True)]
        return out

    def n_cells(self) -> int:
        per_condition = len(self.alphas) * len(self.seeds) if "dqn" in self.policies else 0
        per_condition += len(self.mobil_ps) * len(self.eval_seeds) if "mobil" in self.policies else 0
        return len(self.conditions()) * per_condition


def t_up_for(lanes: int, load: float) -> float:
    """T_up (s, 2 decimals) giving `load` x lanes x 1,800 veh/h."""
    return round(3600.0 / (load * lanes * NOMINAL_CAPACITY_VEH_H_PER_LANE), 2)


def load_of(lanes: int, t_up_s: float) -> float:
    return round(3600.0 / (t_up_s * lanes * NOMINAL_CAPACITY_VEH_H_PER_LANE), 4)


def eval_seeds(n: int) -> tuple[int, ...]:
    """The first n evaluation seeds."""
    return tuple(EVAL_SEED_BASE + i for i in range(1, n + 1))


PROFILES = {
    "tiny": Profile("tiny", lanes=(2,), loads=(0.25, 0.5), alphas=(0.0, 8.0), seeds=(1, 2),
                    train_steps=300, eval_steps=300, mobil_ps=(0.0, 1.0)),
    "quick": Profile("quick", lanes=(2, 3, 4), loads=(0.25, 0.5, 0.75, 1.0), alphas=QUICK_ALPHAS,
                     seeds=(1, 2, 3), train_steps=8000, eval_steps=3000, eval_seeds=eval_seeds(3)),
    "paper": Profile("paper", lanes=(2, 3, 4, 5, 6), loads=(0.2, 0.4, 0.6, 0.8, 1.0), alphas=PAPER_ALPHAS,
                     seeds=tuple(range(1, 11)), train_steps=90_000, eval_steps=9000, eval_seeds=eval_seeds(5)),
}  # fmt: skip


def cell_key(lanes: int, t_up_s: float, alpha: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_a{number_name(alpha)}_s{seed}"


def conditioned_key(lanes: int, t_up_s: float, seed: int) -> str:
    """The training folder of a conditioned sweep's (condition, seed), shared by its cells of every alpha."""
    return f"L{lanes}_T{number_name(t_up_s)}_cond_s{seed}"


def mobil_key(lanes: int, t_up_s: float, p: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_mobil_p{number_name(p)}_s{seed}"


def train_config(lanes: int, t_up_s: float, alpha: float, seed: int, profile: Profile) -> TrainConfig:
    """Scenario II training (free flow at the condition's own inflow, as the paper trains, whatever the preset's
    training demand), without an evaluation of its own: eval_configs are the model's evaluations."""
    sim = SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=t_up_s),
        reward=RewardConfig(alpha=alpha),
        steps=profile.train_steps,
        seed=seed,
        policy="dqn",
    )
    return TrainConfig(sim=sim, dqn=at_condition(DQN_PRESETS[profile.preset]), eval_steps=0)


def eval_configs(lanes: int, t_up_s: float, alpha: float, profile: Profile) -> list[SimConfig]:
    """The greedy evaluations of a model of the condition at `alpha` (policy "dqn": the cell names the model), one
    per evaluation seed: free flow, the condition's inflow, eval_steps each."""
    return [SimConfig(road=RoadConfig(lanes=lanes), demand=DemandConfig(t_up_s=t_up_s),
                      reward=RewardConfig(alpha=alpha), steps=profile.eval_steps, seed=s, policy="dqn")
            for s in profile.eval_seeds]  # fmt: skip


def at_condition(dqn: DQNConfig) -> DQNConfig:
    """The learner trained on its condition alone: free flow at the run's own inflow (no drawn demands, no
    accidents, none in the model selection either), so each condition's alpha* is learned where it is judged."""
    return replace(dqn, train_t_ups=(), accident_share=0.0, validation_accident_steps=0)


def conditioned_train_config(lanes: int, t_up_s: float, seed: int, profile: Profile) -> TrainConfig:
    """The alpha-conditioned training of a (condition, seed), shared by the cells of every alpha (no evaluation of
    its own: each cell evaluates it at its alpha, eval_configs)."""
    dqn = replace(at_condition(DQN_PRESETS[profile.preset]), alpha_conditioned=True)
    sim = SimConfig(road=RoadConfig(lanes=lanes), demand=DemandConfig(t_up_s=t_up_s), steps=profile.train_steps,
                    seed=seed, policy="dqn")  # fmt: skip
    return TrainConfig(sim=sim, dqn=dqn, eval_steps=0)


def mobil_config(lanes: int, t_up_s: float, p: float, seed: int, profile: Profile) -> SimConfig:
    """A MOBIL cell: one run of mobil:p=P on evaluation seed `seed`, as a DQN model's evaluation there (free flow,
    condition, steps)."""
    return SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=t_up_s),
        steps=profile.eval_steps,
        seed=seed,
        policy=f"mobil:p={p}",
    )


def cell_specs(profile: Profile) -> list[dict[str, Any]]:
    """One JSON-ready spec per cell: key, coordinates and the full configuration as a dict.

    A DQN cell is one model (condition, alpha, training seed): its configuration is {"train": TrainConfig, "evals":
    [SimConfig per evaluation seed]}; a conditioned cell's the same, its spec naming the training folder its alphas
    share (train_key). A MOBIL cell is one run (condition, p, evaluation seed): its configuration a SimConfig, its
    seed the evaluation seed.
    """
    specs = []

    def add(key: str, lanes: int, t_up: float, load: float, seed: int, policy: str, alpha: float | None,
            p: float | None, cfg: TrainConfig | SimConfig | dict[str, Any], **extra: Any) -> None:  # fmt: skip
        specs.append({"key": key, "lanes": lanes, "t_up_s": t_up, "load": load, "alpha": alpha, "seed": seed,
                      "policy": policy, "p": p, **extra,
                      "config": json.loads(json.dumps(cfg if isinstance(cfg, dict) else to_dict(cfg)))})  # fmt: skip

    for lanes, t_up, load in profile.conditions():
        if "dqn" in profile.policies:
            for alpha in profile.alphas:
                evals = eval_configs(lanes, t_up, alpha, profile)
                for seed in profile.seeds:
                    if profile.conditioned:
                        train = conditioned_train_config(lanes, t_up, seed, profile)
                        extra = {"train_key": conditioned_key(lanes, t_up, seed)}
                    else:
                        train, extra = train_config(lanes, t_up, alpha, seed, profile), {}
                    train.validate()
                    for ev in evals:
                        ev.validate()
                    config = {"train": to_dict(train), "evals": [to_dict(ev) for ev in evals]}
                    add(cell_key(lanes, t_up, alpha, seed), lanes, t_up, load, seed, "dqn", alpha, None, config,
                        **extra)  # fmt: skip
        if "mobil" in profile.policies:
            for p in profile.mobil_ps:
                for seed in profile.eval_seeds:
                    cfg = mobil_config(lanes, t_up, p, seed, profile)
                    cfg.validate()
                    add(mobil_key(lanes, t_up, p, seed), lanes, t_up, load, seed, "mobil", None, p, cfg)
    return specs
