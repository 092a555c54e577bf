"""The learner protocol's plan: its learners, profiles and cells (studies/protocol.py runs them).

A variant is a training (its learner) plus which weights drive: `model.pt` (the validated best, when the learner
selects) or `model_last.pt` (the last weights). Every model meets every condition on the same evaluation seeds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from itertools import product
from typing import Any

from coopsumo.agents.conditioning import CONDITIONED8V, world_alpha
from coopsumo.config import (
    ALPHA_ONLY_DQN,
    MIN_ACCIDENT_VALIDATION_STEPS,
    AccidentConfig,
    DemandConfig,
    DQNConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.studies.model_store import FIRST_TRAIN_SEED
from coopsumo.validation import number_name

EVAL_SEED = 5000
"""evaluation run of condition i uses seed EVAL_SEED + i (free flow) or EVAL_SEED + 100 + i (accident), each plus
one of the profile's eval_offsets"""
TRAIN_SEED = FIRST_TRAIN_SEED
"""first training seed of the protocol (the committed learning studies used 0-8)"""
BASELINES = ("keep", "greedy", "mobil:p=0")
DEMANDS = (2.0, 1.5, 1.0)
TRAJECTORY_EVERY = 5
"""accident runs record trajectories every 5 steps (0.5 s) for total time spent"""
REQUIRED = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")


DRIVES = (("margin", "change_margin", "change margin"), ("cooldown", "change_cooldown_s", "lane-change cooldown (s)"),
          ("noreturn", "no_return_s", "no change back within (s)"),
          ("restart", "restart_below_mps", "'none' withheld below (m/s)"),
          ("queue", "queue_below_mps", "no lane change below (m/s)"),
          ("ensemble", "ensemble_snapshots", "best-validated snapshots averaged"))
"""how a variant may drive its trainings otherwise: its field (also the key of the dqn policy string), the key in a
cell's config.drive, and the report's words"""


@dataclass(frozen=True)
class Variant:
    """A learner as judged: the training (its learner settings) and the weights that drive."""

    name: str
    text: str
    learner: DQNConfig
    weights: str = "model.pt"
    margin: float | None = None
    """the change margin it drives with (Q units; None: the learner's own); the trainings are the same"""
    cooldown: float | None = None
    """the lane-change cooldown it drives with (s; None: none)"""
    noreturn: float | None = None
    """how long after a lane change it does not choose the change back (s; None: no such rule)"""
    restart: float | None = None
    """the speed below which it withholds 'none' (m/s; None: the learner's own)"""
    queue: float | None = None
    """the speed below which it chooses no lane change (m/s; None: none)"""
    ensemble: int | None = None
    """how many best-validated snapshots of its training it averages the Q-values of (None: model.pt alone)"""

    def drive(self) -> dict[str, float]:
        """How it drives its trainings otherwise (a cell's config.drive; empty: as saved)."""
        return {key: getattr(self, field) for field, key, _ in DRIVES if getattr(self, field) is not None}


SELECT = replace(DQNConfig(), observation="paper", train_t_ups=(), accident_share=0.0, validation_accident_steps=0,
                 followers_weight=0.0, queue_below_mps=0.0, target_sync_steps=500, no_return_s=0.0)
"""the default learner before the v2x state and the mix (free flow at the run's own demand, the paper's state,
model.pt chosen on free flow alone)"""
MIX = replace(SELECT, train_t_ups=(2.0, 1.5, 1.0), accident_share=0.5, episode_steps=9000)
"""the learner trained on the mix of demands and accidents (agents/episodes.py)"""
V2X_MIX = replace(MIX, observation="v2x")
"""the v2x state trained on the mix, model.pt chosen on free flow alone (the default until v2x_mix_av)"""
V2X_MIX_AV = replace(V2X_MIX, validation_accident_steps=6000)
"""v2x_mix with model.pt chosen through an accident too (the default preset from 2026-11-26 to 11-27)"""
V2X_MIX_AV_F05 = replace(V2X_MIX_AV, followers_weight=0.5)
"""v2x_mix_av trained with half the weight on the speed of the traffic behind (--followers-weight 0.5)"""
F05Q = replace(V2X_MIX_AV_F05, queue_below_mps=5.0)
"""the candidate default of 2026-11-27 (not the preset): v2x_mix_av_f05 driving with no lane change below 5 m/s, the
queue rule in its own settings (--queue-below 5; v2x_mix_av_f05_q5's trainings and drive as one learner)"""
F05Q_TS2K = replace(F05Q, target_sync_steps=2000)
"""the default preset from 2026-11-27 to 11-28: f05q with the target network synced every 2,000 steps"""
NR10 = replace(F05Q_TS2K, no_return_s=10.0)
"""the default preset (DQNConfig()): f05q_ts2k with no change back for 10 s in its settings"""


def variants() -> dict[str, Variant]:
    """The variants the protocol knows; `nr10` is the default preset (DQNConfig()), `f05q_ts2k` the one before."""
    default = SELECT
    return {v.name: v for v in (
        Variant("select", "the default until v2x_mix: the paper's state, free-flow training at T_up 1 s, change "
                "margin 1, model.pt chosen on held-out demand "
                "(validated every 15,000 steps)", default),
        Variant("margin", "the previous default: the same trainings' last weights (model_last.pt), change margin 1",
                default, "model_last.pt"),
        Variant("mix", "`select` trained where it is used: episodes of 9,000 steps, each at a T_up drawn from 2, 1.5 "
                "and 1 s, half of them with an accident (position, start and length drawn)", MIX),
        Variant("mix_last", "the `mix` trainings' last weights", MIX, "model_last.pt"),
        Variant("v2x", "`select` reading the v2x state: the paper's state plus each side lane's nearest leader and "
                "follower within 200 m (gap, speed)", replace(SELECT, observation="v2x")),
        Variant("v2x_mix", "`v2x` trained where it is used, as `mix` (the default until `v2x_mix_av`)",
                V2X_MIX),
        Variant("v2x_mix_m2", "`v2x_mix`'s trainings driven with a change margin of 2 instead of 1",
                V2X_MIX, margin=2.0),
        Variant("v2x_mix_m4", "`v2x_mix`'s trainings driven with a change margin of 4 instead of 1",
                V2X_MIX, margin=4.0),
        Variant("v2x_mix_cd10", "`v2x_mix`'s trainings driven with a lane-change cooldown of 10 s (no change chosen "
                "within 10 s of the last one's end)", V2X_MIX, cooldown=10.0),
        Variant("v2x_mix_cd30", "`v2x_mix`'s trainings driven with a lane-change cooldown of 30 s",
                V2X_MIX, cooldown=30.0),
        Variant("v2x_mix_r5", "`v2x_mix`'s trainings driven with 'none' withheld below 5 m/s instead of 1 (a vehicle "
                "in a queue always asks to speed up)", V2X_MIX, restart=5.0),
        Variant("v2x_mix_lanes", "`v2x_mix`'s trainings choosing lanes only: 'none' never offered, so every vehicle "
                "that stays asks to speed up, as `keep` does", V2X_MIX, restart=50.0),
        Variant("v2x_mix_av", "`v2x_mix` with model.pt chosen through an accident too: each snapshot also driven "
                "6,000 steps through an accident at T_up 2, 1.5 and 1 s (--validation-accident-steps 6000; the "
                "same trainings, judged again; the default preset)", V2X_MIX_AV),
        Variant("v2x_mix_av_q5", "the default's trainings (`v2x_mix_av`) choosing no lane change below 5 m/s, in a "
                "queue (dqn:PATH,queue=5)", V2X_MIX_AV, queue=5.0),
        Variant("v2x_mix_av_f1", "the default (`v2x_mix_av`) trained with the speed of the traffic behind in its "
                "reward: each step, plus the mean speed reward of the vehicles within 50 m behind in the lanes a "
                "vehicle occupies (--followers-weight 1)", replace(V2X_MIX_AV, followers_weight=1.0)),
        Variant("v2x_mix_av_f05", "`v2x_mix_av_f1` with half the weight on the traffic behind (--followers-weight "
                "0.5)", V2X_MIX_AV_F05),
        Variant("v2x_mix_av_f05_q5", "`v2x_mix_av_f05`'s trainings choosing no lane change below 5 m/s, in a queue "
                "(dqn:PATH,queue=5): the trained remedy and the drive-time one together",
                V2X_MIX_AV_F05, queue=5.0),
        Variant("f05q", "the candidate default before `f05q_ts2k`: `v2x_mix_av_f05` with the queue rule in its "
                "settings (--queue-below 5: no lane change chosen below 5 m/s when it drives; training and model "
                "selection as `v2x_mix_av_f05`)", F05Q),
        Variant("f05q_m05", "`f05q`'s trainings driven with a change margin of 0.5 instead of 1",
                F05Q, margin=0.5),
        Variant("f05q_m0", "`f05q`'s trainings driven with no change margin (plain argmax)", F05Q,
                margin=0.0),
        Variant("f05q_q8", "`f05q`'s trainings choosing no lane change below 8 m/s instead of 5", F05Q,
                queue=8.0),
        Variant("f05q_r5", "`f05q`'s trainings driven with 'none' withheld below 5 m/s instead of 1 (a vehicle in a "
                "queue that stays always asks to speed up)", F05Q, restart=5.0),
        Variant("f05q_lanes", "`f05q`'s trainings choosing lanes only: 'none' never offered (withheld below 50 m/s), "
                "so every vehicle that stays asks to speed up, as `keep` and `greedy` do", F05Q, restart=50.0),
        Variant("f05q_g95", "`f05q` trained with a discount of 0.95 per decision round (about a 20 s horizon) instead "
                "of 0.9 (10 s): does a longer horizon buy the passing a slower leader pays for later?",
                replace(F05Q, gamma=0.95)),
        Variant("f05q_vq", "`f05q`'s trainings with each snapshot validated as it will drive, with the queue rule on "
                "(--validation-queue; the same weights, model.pt chosen again)",
                replace(F05Q, validation_queue=True)),
        Variant("f05q_ens3", "`f05q`'s trainings driven with the mean Q-value of each training's 3 best-validated "
                "snapshots, model.pt among them (dqn:PATH,ensemble=3): the same weights, a steadier choice?",
                F05Q, ensemble=3),
        Variant("f05q_ts2k", "the default preset: `f05q` with the target network synced every 2,000 steps instead of "
                "500 (about 400 updates instead of 100): do the snapshots of one training swing less?",
                F05Q_TS2K),
        Variant("f05q_lr3", "`f05q` trained with Adam's learning rate at 3e-4 instead of 1e-3: smaller steps, do the "
                "snapshots of one training swing less?", replace(F05Q, lr=3e-4)),
        Variant("f05q_ema", "`f05q` driven by a moving average of its online weights (decay 0.999 per gradient "
                "update, a time constant of about 1,000 updates or 5,000 steps): the same training, steadier "
                "snapshots?", replace(F05Q, weights_ema=0.999)),
        Variant("f05q_ts2k_cd10", "`f05q_ts2k`'s trainings driven with a lane-change cooldown of 10 s (no change "
                "chosen within 10 s of the last one's end): does it bring the busiest model under 3 lane changes per "
                "vehicle without costing free flow?", F05Q_TS2K, cooldown=10.0),
        Variant("f05q_ts2k_nr10", "`f05q_ts2k`'s trainings driven without the change back: for 10 s after a lane "
                "change's end the change into the lane it left is not chosen (a change onward stays offered): does "
                "the busiest model stop changing back and forth (a third of its changes undone within 5 s) without "
                "the cooldown's cost through the accident?", F05Q_TS2K, noreturn=10.0),
        Variant("nr10", "the default preset: `f05q_ts2k` with no change back for 10 s in its settings (--no-return "
                "10): model.pt chosen and driven so (`f05q_ts2k_nr10` drove `f05q_ts2k`'s model.pt so)", NR10),
        Variant("c2x", "the default (`nr10`) trained as one alpha-conditioned network (alphas up to 8 drawn and "
                "relabelled to, model.pt chosen at alphas 0, 1 and 8: the learning study's `conditioned8v`), driven "
                "at the cell's alpha; its profile trains it 180,000 steps (`conditioned8v_2x`)",
                replace(NR10, **CONDITIONED8V)),
        Variant("f05q_ts2k_n3", "`f05q_ts2k` learning from 3-round returns (--n-step 3, bootstrapped with gamma^3): "
                "does the speed a lane change buys reach the decision that made it sooner than through the target's "
                "estimate?", replace(F05Q_TS2K, n_step=3)),
        Variant("alpha_only", "the default's learning machinery with alpha as its only cooperative mechanism (the "
                "`alpha_only` preset: no followers' term in the reward, no queue rule, no change-back rule, no change "
                "margin), trained in free flow at T_up 2, 1.5 and 1 s and chosen on free flow alone, as the paper "
                "trained; the learner of claim (a) as the paper poses it", ALPHA_ONLY_DQN),
        Variant("gamma", "`select` with a discount of 0.97 per decision round (about a 33 s horizon) instead of 0.9 "
                "(10 s)", replace(SELECT, gamma=0.97)),
    )}  # fmt: skip


@dataclass(frozen=True)
class Profile:
    name: str
    variants: tuple[str, ...] = ("select", "margin")
    seeds: tuple[int, ...] = tuple(range(TRAIN_SEED, TRAIN_SEED + 10))
    train_steps: int = 90_000
    t_ups: tuple[float, ...] = DEMANDS
    free_steps: int = 6000
    accident_steps: int = 20_000
    accident_start: int = 2000
    accident_duration: int = 10_000
    alpha_seeds: int = 3
    """models at alpha 8 of the judged variant (free flow only): does alpha do something?"""
    lanes: int = 3
    eval_offsets: tuple[int, ...] = (0,)
    """each is added to every evaluation seed, one evaluation per offset (10: seeds 5010+i and 5110+i): every model
    and baseline meets each condition on len(eval_offsets) seeds, and the report judges each by its mean over them"""
    judged: str = ""
    """the variant whose targets and alpha response the report gives (empty: the first; the others are paired
    against the first)"""
    paired_with: tuple[tuple[str, str, str], ...] = ()
    """(a variant here, a committed protocol report's folder under results/, a variant there): the report pairs the
    two by training seed when that study ran the same seeds, demands and step counts with today's learner of that
    variant (protocol_report.committed_pair_lines), so that trainings made once need not be made again"""

    def judged_variant(self) -> str:
        return self.judged or self.variants[0]


PROFILES = {
    "default": Profile("default"),
    "mix": Profile("mix", variants=("mix", "mix_last"), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)), alpha_seeds=0),
    "gamma": Profile("gamma", variants=("gamma",), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)), alpha_seeds=0),
    "v2x": Profile("v2x", variants=("v2x", "v2x_mix"), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)), alpha_seeds=0),
    "v2x_mix10": Profile("v2x_mix10", variants=("v2x_mix",)),  # v2x_mix on the default's 10 seeds, alpha 8 on 3
    "drive": Profile("drive", variants=("v2x_mix", "v2x_mix_m2", "v2x_mix_m4", "v2x_mix_cd10", "v2x_mix_cd30"),
                     seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)), alpha_seeds=0),  # the default driven otherwise
    "cooldown": Profile("cooldown", variants=("v2x_mix", "v2x_mix_cd10")),  # the 10 s cooldown on 10 models
    "restart": Profile("restart", variants=("v2x_mix", "v2x_mix_r5", "v2x_mix_lanes"), alpha_seeds=0),  # 'none'?
    "accval": Profile("accval", variants=("v2x_mix", "v2x_mix_av"), judged="v2x_mix_av"),  # the default since 11-26
    "queue": Profile("queue", variants=("v2x_mix_av", "v2x_mix_av_q5"), judged="v2x_mix_av_q5", alpha_seeds=0),
    "followers": Profile("followers", variants=("v2x_mix_av", "v2x_mix_av_f1"),
                         judged="v2x_mix_av_f1",
                         seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)), alpha_seeds=0),  # a trained remedy, first look
    "followers05": Profile("followers05", variants=("v2x_mix_av_f05", "v2x_mix_av_f05_q5"),
                           alpha_seeds=0,  # the default's 10 seeds, as learner_protocol_queue
                           paired_with=(("v2x_mix_av_f05", "learner_protocol_queue", "v2x_mix_av"),
                                        ("v2x_mix_av_f05", "learner_protocol_followers", "v2x_mix_av_f1"),
                                        ("v2x_mix_av_f05_q5", "learner_protocol_queue", "v2x_mix_av_q5"),
                                        ("v2x_mix_av_f05_q5", "learner_protocol_queue", "v2x_mix_av"))),
    "f05q": Profile("f05q", variants=("f05q", "f05q_m05", "f05q_m0", "f05q_q8", "f05q_r5", "f05q_lanes"),
                    paired_with=(("f05q", "learner_protocol_followers05", "v2x_mix_av_f05_q5"),
                                 ("f05q", "learner_protocol_queue", "v2x_mix_av")),
                    judged="f05q"),  # the candidate before f05q_ts2k; alpha 8 on 3 models; the others drive it
    "f05q_e1": Profile("f05q_e1", variants=("f05q", "f05q_m05", "f05q_m0", "f05q_q8"), alpha_seeds=0,
                       eval_offsets=(10,)),  # f05q's trainings on fresh evaluation seeds: does its verdict replicate?
    "f05q_g95": Profile("f05q_g95", variants=("f05q_g95",), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)),
                        alpha_seeds=0,
                        paired_with=(("f05q_g95", "learner_protocol_f05q", "f05q"),)),  # the discount, a first look
    "f05q_vq": Profile("f05q_vq", variants=("f05q_vq",), alpha_seeds=0,
                       paired_with=(("f05q_vq", "learner_protocol_f05q", "f05q"),)),  # one change: selection
    "f05q_ens": Profile("f05q_ens", variants=("f05q_ens3",), alpha_seeds=0,
                        paired_with=(("f05q_ens3", "learner_protocol_f05q", "f05q"),)),  # one change: 3 snapshots
    "f05q_ens_e2": Profile("f05q_ens_e2", variants=("f05q", "f05q_ens3"), alpha_seeds=0,
                           eval_offsets=(20,)),  # the ensemble against f05q on evaluation seeds no study used before
    "f05q_ts2k": Profile("f05q_ts2k", variants=("f05q_ts2k",), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)),
                         alpha_seeds=0,
                         paired_with=(("f05q_ts2k", "learner_protocol_f05q", "f05q"),)),  # a steadier target
    "f05q_ts2k10": Profile("f05q_ts2k10", variants=("f05q_ts2k",),  # the same on 10 seeds, alpha 8 on 3
                           paired_with=(("f05q_ts2k", "learner_protocol_f05q", "f05q"),)),
    "f05q_ts2k_e2": Profile("f05q_ts2k_e2", variants=("f05q_ts2k",), alpha_seeds=0, eval_offsets=(20,),
                            paired_with=(("f05q_ts2k", "learner_protocol_f05q_ens_e2", "f05q"),)),  # fresh seeds
    "f05q_lr3": Profile("f05q_lr3", variants=("f05q_lr3",), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)),
                        alpha_seeds=0,
                        paired_with=(("f05q_lr3", "learner_protocol_f05q", "f05q"),)),  # smaller steps
    "f05q_ema": Profile("f05q_ema", variants=("f05q_ema",), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)),
                        alpha_seeds=0,
                        paired_with=(("f05q_ema", "learner_protocol_f05q", "f05q"),)),  # averaged weights
    "f05q_ts2k_n3": Profile("f05q_ts2k_n3", variants=("f05q_ts2k_n3",), seeds=tuple(range(TRAIN_SEED, TRAIN_SEED + 5)),
                            alpha_seeds=0,
                            paired_with=(("f05q_ts2k_n3", "learner_protocol_f05q_ts2k10", "f05q_ts2k"),)),  # n-step
    "f05q_ts2k_cd10": Profile("f05q_ts2k_cd10", variants=("f05q_ts2k", "f05q_ts2k_cd10"),
                              alpha_seeds=0),  # the default's 10 models with the 10 s cooldown, paired by model
    "f05q_ts2k_3sets": Profile("f05q_ts2k_3sets", variants=("f05q_ts2k",), alpha_seeds=0,
                               eval_offsets=(0, 20, 40)),  # the default's 10 models on 3 seeds per condition
    "f05q_ts2k_nr10": Profile("f05q_ts2k_nr10", variants=("f05q_ts2k", "f05q_ts2k_nr10"), alpha_seeds=0,
                              eval_offsets=(0, 20, 40)),  # the default's 10 models without the change back, by model
    "c2x": Profile("c2x", variants=("c2x",), train_steps=180_000),  # one conditioned network per seed, alpha 8 on 3
    "nr10_180k": Profile("nr10_180k", variants=("nr10",), train_steps=180_000,
                         alpha_seeds=0),  # the default trained as long: is c2x's gain the steps or the conditioning?
    "nr10": Profile("nr10", variants=("nr10",),  # the default on 10 seeds, alpha 8 on 3, paired by model
                    paired_with=(("nr10", "learner_protocol_f05q_ts2k10", "f05q_ts2k"),)),
    "nr10_3sets": Profile("nr10_3sets", variants=("nr10",), alpha_seeds=0,
                          eval_offsets=(0, 20, 40)),  # the default's 10 models on 3 seeds per condition
    "alpha_only": Profile("alpha_only", variants=("alpha_only",),  # claim (a)'s learner: does it learn? alpha 8 on 3
                          paired_with=(("alpha_only", "learner_protocol_nr10", "nr10"),)),  # against the default
    "tiny": Profile("tiny", seeds=(TRAIN_SEED, TRAIN_SEED + 1), train_steps=600, t_ups=(1.5, 1.0), free_steps=300,
                    accident_steps=600, accident_start=100, accident_duration=300, alpha_seeds=1),
}  # fmt: skip
CURRENT = "nr10"
"""the profile that judges today's default learner (DQNConfig()): `coopsumo protocol` and `make protocol` run it when
no profile is named (its committed report: results/learner_protocol_nr10); the profile named `default` is the first
protocol's, of an older learner"""
OLDEST = "default"
"""the first protocol's profile; its folder is results/learner_protocol, any other's results/learner_protocol_<name>"""


def train_config(profile: Profile, dqn: DQNConfig, alpha: float, seed: int) -> TrainConfig:
    """A model's training (a conditioned one's world at alpha 0: conditioning.world_alpha)."""
    sim = SimConfig(road=RoadConfig(lanes=profile.lanes), reward=RewardConfig(alpha=world_alpha(dqn, alpha)),
                    steps=profile.train_steps, seed=seed, policy="dqn")  # fmt: skip
    if profile.train_steps < dqn.select_every_steps:  # a short profile validates twice
        dqn = replace(dqn, select_every_steps=max(profile.train_steps // 2, 1), validation_steps=min(
            dqn.validation_steps, profile.free_steps))  # fmt: skip
        if dqn.validation_accident_steps:
            dqn = replace(dqn, validation_accident_steps=max(MIN_ACCIDENT_VALIDATION_STEPS, min(
                dqn.validation_accident_steps, profile.accident_steps)))  # fmt: skip
    return TrainConfig(sim=sim, dqn=dqn, eval_steps=0)


def eval_config(profile: Profile, scenario: str, i: int, policy: str, alpha: float = 0.0, offset: int = 0) -> SimConfig:
    """The evaluation run of condition i (its demand profile.t_ups[i]) in free flow or through the accident, on the
    evaluation seed of `offset` (one of profile.eval_offsets)."""
    t_up = profile.t_ups[i]
    if scenario == "free":
        return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=t_up),
                         reward=RewardConfig(alpha=alpha), steps=profile.free_steps,
                         seed=EVAL_SEED + offset + i,
                         policy=policy)  # fmt: skip
    return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=t_up),
                     accident=AccidentConfig(enabled=True, start_step=profile.accident_start,
                                             duration_steps=profile.accident_duration),
                     reward=RewardConfig(alpha=alpha), steps=profile.accident_steps,
                     seed=EVAL_SEED + 100 + offset + i,
                     policy=policy)  # fmt: skip


def cell_specs(profile: Profile) -> list[dict[str, Any]]:
    """Every cell: one per (variant, alpha, training seed, scenario, demand, evaluation seed set) and per (baseline,
    scenario, demand, evaluation seed set)."""
    known = variants()
    specs: list[dict[str, Any]] = []
    models: list[tuple[Variant, float, int, tuple[str, ...]]] = []
    for name in profile.variants:
        for seed in profile.seeds:
            models.append((known[name], 0.0, seed, ("free", "accident")))
    judged = known[profile.judged_variant()]
    for seed in profile.seeds[: profile.alpha_seeds]:
        models.append((judged, 8.0, seed, ("free",)))
    for variant, alpha, seed, scenarios in models:
        cfg = train_config(profile, variant.learner, alpha, seed)
        train_key = f"a{number_name(alpha)}_seed{seed}_{_learner_tag(variant.learner)}"
        for scenario, (i, t_up), offset in product(scenarios, enumerate(profile.t_ups), profile.eval_offsets):
            ev = eval_config(profile, scenario, i, "dqn", alpha, offset)
            key = f"{variant.name}_a{number_name(alpha)}_seed{seed}_{scenario}_t{number_name(t_up)}"
            key += _set_suffix(profile, offset)
            config: dict[str, Any] = {"train": to_dict(cfg), "eval": to_dict(ev)}
            if variant.drive():  # part of the cell's identity: a record driven otherwise is rerun
                config["drive"] = variant.drive()
            specs.append({"key": key, "kind": "model", "variant": variant.name, "alpha": alpha, "seed": seed,
                          "scenario": scenario, "t_up": t_up, "eval_seed": ev.seed, "weights": variant.weights,
                          "train_key": train_key,
                          "config": json.loads(json.dumps(config))})  # fmt: skip
    for policy in BASELINES:
        for scenario, (i, t_up), offset in product(("free", "accident"), enumerate(profile.t_ups),
                                                   profile.eval_offsets):  # fmt: skip
            ev = eval_config(profile, scenario, i, policy, offset=offset)
            key = f"{policy.replace(':', '_').replace('=', '')}_{scenario}_t{number_name(t_up)}"
            specs.append({"key": key + _set_suffix(profile, offset),
                          "kind": "baseline", "variant": policy, "alpha": 0.0, "seed": None, "scenario": scenario,
                          "t_up": t_up, "eval_seed": ev.seed, "weights": None, "train_key": None,
                          "config": json.loads(json.dumps({"eval": to_dict(ev)}))})  # fmt: skip
    return specs


def _set_suffix(profile: Profile, offset: int) -> str:
    """The cell key's suffix of an evaluation seed set: none for the profile's first (so that a profile given more
    sets keeps its cells), `_e<offset>` for the others."""
    return "" if offset == profile.eval_offsets[0] else f"_e{offset}"


def _learner_tag(dqn: DQNConfig) -> str:
    """A short name of a learner for its training folder: the preset, and a digest of its settings."""
    import hashlib

    digest = hashlib.sha256(json.dumps(to_dict(dqn), sort_keys=True).encode()).hexdigest()[:8]
    return f"{dqn.preset}_{digest}"
