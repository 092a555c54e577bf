"""Train Stable-Baselines3's DQN on `coopsumo/Highway-v0` (one agent among background traffic).

    .venv/bin/python experiments/sb3_dqn.py --steps 20000 --out results/sb3_dqn

Needs the optional extra `sb3` (stable-baselines3). The Q-network is the paper's (Table II):
a features extractor made of coopsumo.agents.dqn.QNetwork's layers (two 2x2 convolutions, stride (1, 2),
concat the 3 speed errors, FC 500, FC 100) and SB3's final linear layer to the 4 Q-values
(net_arch=[]). SB3 receives the Dict observation through its "MultiInputPolicy". Learning
hyper-parameters are coopsumo's paper preset (PAPER_DQN: one decision per 0.1 s step): lr, gamma,
replay size, batch, an update every 4 steps, target sync every 500 steps, a constant epsilon of 0.1.

Prints `episodes=N mean_episode_reward=R ...` over the finished episodes (nan if none finished).
With --out, writes model.zip (SB3's format), config.json and summary.json into that folder; the model then drives
every vehicle in `coopsumo simulate --policy sb3:OUT/model.zip` and as a study's baseline (docs/extending.md).
Bad input (every value checked as the commands check it, coopsumo.validation): one line on stderr, exit code 2,
nothing written; without stable-baselines3 installed, one line saying how to install it.

An example, not a `coopsumo` command: it uses the package from outside, as a user of the Gymnasium interface would
(a third-party learner on `coopsumo/Highway-v0`), and it is no study (one training, no cells). The commands live in
the layers below the interfaces (studies -> agents -> sim), which never import coopsumo.envs.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from coopsumo.config import ControlConfig, DemandConfig, RewardConfig, RoadConfig, SimConfig, to_dict
from coopsumo.dqn_config import PAPER_DQN
from coopsumo.errors import UsageError
from coopsumo.files import write_json
from coopsumo.owners import owned_problem
from coopsumo.provenance import package_version, versions
from coopsumo.run_dirs import atomic_run_dir
from coopsumo.run_markers import SB3_KIND
from coopsumo.runio import Parser, run_cli, run_interruptible
from coopsumo.validation import (
    MAX_STEPS,
    MAX_T_UP_S,
    alpha,
    integer,
    min_t_up_s,
    number,
    out_dir,
    seed,
    steps,
    t_up_note,
)


def build_parser() -> Parser:
    dt_s = ControlConfig().dt_s
    p = Parser(prog="experiments/sb3_dqn.py", description="Train SB3's DQN on coopsumo/Highway-v0.")
    p.add_argument("--steps", type=steps, default=20_000, help="agent steps of 0.1 s to train for")
    p.add_argument("--out", type=out_dir, default=None,
                   help="folder for model.zip, config.json, summary.json (default: none, nothing written)")
    p.add_argument("--seed", type=seed, default=0, help="seed of SB3 and of the first episode")
    p.add_argument("--lanes", type=integer(2, 6), default=3, help="number of lanes")
    p.add_argument("--t-up", type=number(min_t_up_s(dt_s), MAX_T_UP_S, note=t_up_note(dt_s)),
                   default=DemandConfig.t_up_s, help="upstream departure interval (s)")
    p.add_argument("--alpha", type=alpha, default=RewardConfig.alpha, help="lane-change penalty of eq. (7)")
    p.add_argument("--warmup", type=integer(0, MAX_STEPS), default=300,
                   help="steps of background traffic before each episode")
    p.add_argument("--max-steps", type=steps, default=3000, help="agent steps before an episode is truncated")
    p.add_argument("--background", default="keep", help="policy of the other vehicles: keep, greedy, mobil, ...")
    p.add_argument("--threads", type=integer(1, 256), default=1,
                   help="torch threads (the network is small: 1 is fastest)")
    return p


def table_ii_extractor_class() -> type:
    """SB3 features extractor of Table II, built from coopsumo.agents.dqn.QNetwork's layers (imports torch and SB3)."""
    import torch
    from gymnasium import spaces
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    from coopsumo.agents.dqn import QNetwork

    class TableIIExtractor(BaseFeaturesExtractor):  # type: ignore[misc]
        """grids (B, 3, 3, 20) and speed errors (B, 3) m/s -> 100 features (QNetwork without its output layer)."""

        def __init__(self, observation_space: spaces.Dict, speed_scale_mps: float) -> None:
            net = QNetwork(speed_scale_mps)
            super().__init__(observation_space, features_dim=net.fc2.out_features)
            self.speed_scale_mps = speed_scale_mps
            self.conv1, self.conv2, self.fc1, self.fc2 = net.conv1, net.conv2, net.fc1, net.fc2

        def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
            x = torch.relu(self.conv1(observations["grids"]))
            x = torch.relu(self.conv2(x))
            x = torch.cat([x.flatten(start_dim=1), observations["speed_err"] / self.speed_scale_mps], dim=1)
            return torch.relu(self.fc2(torch.relu(self.fc1(x))))

    return TableIIExtractor


def train(args: Any, run_dir: Path | None) -> dict[str, Any]:
    import gymnasium as gym
    import torch
    from stable_baselines3 import DQN
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.monitor import Monitor

    from coopsumo.agents.policies import PolicySpecError
    from coopsumo.envs import ENV_ID

    cfg = SimConfig(
        road=RoadConfig(lanes=args.lanes),
        demand=DemandConfig(t_up_s=args.t_up),
        reward=RewardConfig(alpha=args.alpha),
        seed=args.seed,
    )
    cfg.validate()
    torch.set_num_threads(args.threads)
    dq = PAPER_DQN
    try:
        env = Monitor(
            gym.make(ENV_ID, cfg=cfg, warmup_steps=args.warmup, max_steps=args.max_steps, background=args.background)
        )
    except PolicySpecError as err:
        raise UsageError(str(err)) from None
    start = time.perf_counter()
    try:
        model = DQN(
            "MultiInputPolicy",
            env,
            learning_rate=dq.lr,
            buffer_size=dq.replay_size,
            learning_starts=dq.learn_start_steps,
            batch_size=dq.batch_size,
            gamma=dq.gamma,
            train_freq=dq.learn_every,
            gradient_steps=1,
            target_update_interval=dq.target_sync_steps,
            exploration_initial_eps=dq.epsilon_start,
            exploration_final_eps=dq.epsilon_end,
            max_grad_norm=dq.grad_clip_norm,
            policy_kwargs={
                "features_extractor_class": table_ii_extractor_class(),
                "features_extractor_kwargs": {"speed_scale_mps": dq.speed_scale_mps},
                "net_arch": [],
            },
            seed=args.seed,
            device="cpu",
        )
        model.set_logger(Logger(folder=None, output_formats=[]))  # SB3's default makes an empty /tmp/SB3-* folder
        model.learn(total_timesteps=args.steps)
        if run_dir is not None:
            model.save(run_dir / "model.zip")
    finally:
        env.close()
    rewards = np.asarray(env.get_episode_rewards(), dtype=float)
    lengths = np.asarray(env.get_episode_lengths(), dtype=float)
    summary: dict[str, Any] = {
        "steps": args.steps,
        "episodes": len(rewards),
        "mean_episode_reward": float(rewards.mean()) if len(rewards) else float("nan"),
        "mean_episode_length": float(lengths.mean()) if len(lengths) else float("nan"),
        "wall_seconds": round(time.perf_counter() - start, 3),
    }
    if run_dir is not None:
        extra = {k: package_version(k) for k in ("stable-baselines3", "gymnasium")}
        write_json(
            run_dir / "config.json",
            {"config": to_dict(cfg), "dqn": to_dict(dq), "args": {k: str(v) for k, v in vars(args).items()},
             "versions": {**versions(), **extra}},
        )  # fmt: skip
        write_json(run_dir / "summary.json", summary)
    return summary


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        import importlib.util

        if importlib.util.find_spec("stable_baselines3") is None:
            raise UsageError("stable-baselines3 is not installed; install it with: pip install .[sb3]")
        if args.out is None:
            summary = train(args, None)
        else:  # as simulate writes its folder (issue 82, probe 19: F1, O1)
            if problem := owned_problem(args.out, f"--out {args.out}"):  # a study's, the store's, a run's folder
                raise UsageError(problem)
            with atomic_run_dir(args.out, SB3_KIND) as tmp:  # its lock held: no other command removes its run
                summary = train(args, tmp)  # its own kind: simulate refuses the folder, and it a simulate run's
        print(
            f"episodes={summary['episodes']} mean_episode_reward={summary['mean_episode_reward']:.4g} "
            f"mean_episode_length={summary['mean_episode_length']:.4g} wall_seconds={summary['wall_seconds']:.1f}"
        )
        return 0

    # a Ctrl-C or SIGTERM anywhere is one line, the partial folder removed (issue 82, probe 19, O2: SIGTERM ended it
    # without a line and left the folder)
    return run_interruptible(lambda: run_cli("sb3_dqn", body), lambda: "sb3_dqn", whole_process=argv is None)


if __name__ == "__main__":
    sys.exit(main())
