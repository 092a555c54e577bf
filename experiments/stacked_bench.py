"""CPU per model-update of the stacked learner (coopsumo.agents.stacked, issue 77) against today's update.

    .venv/bin/python experiments/stacked_bench.py [--rounds 7] [--groups 1,2,4,8,16] [--keep-malloc]

One torch thread, the default learner (DQNConfig(): v2x input, dueling, double DQN, Huber, clipping, Adam), batch
64, random minibatches shaped as the replay's. Today's update is agents/dqn.learn on a QNetwork with
make_optimizer's Adam, as the update worker runs it; a stacked update of a group of K is StackedLearner.learn, one
update of every member, its CPU divided by K. Each round times, for every K, today's update and then the group's,
back to back in this process, so that both see the same load; the ratio of a round is the group's CPU per model
over today's. Prints each round's ratios, then the median and range per K. Takes about a minute on a quiet machine.

The process first asks glibc's malloc to keep freed memory (agents/stacked.hold_freed_memory, as an update worker
serving a group would): without it a group's megabyte-sized temporaries fault in afresh at every update.
--keep-malloc leaves malloc as it is, to measure that.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch

from coopsumo.agents.dqn import QNetwork, learn, make_optimizer, sync_target
from coopsumo.agents.replay import GRID_SHAPE, N_ACTIONS, ReplayBatch
from coopsumo.agents.stacked import StackedLearner, hold_freed_memory, stack_batches
from coopsumo.dqn_config import DQNConfig

POOL = 16
"""distinct minibatches per member, used in turn"""


def random_batch(gen: torch.Generator, width: int, size: int) -> ReplayBatch:
    """A minibatch shaped as ReplayBuffer.sample's: 0/1 grids, features, some next actions closed."""
    mask = torch.rand(size, N_ACTIONS, generator=gen) < 0.6
    mask[:, -1] = True
    return ReplayBatch(
        grids=(torch.rand(size, *GRID_SHAPE, generator=gen) < 0.2).float(),
        features=torch.randn(size, width, generator=gen) * 3,
        actions=torch.randint(0, N_ACTIONS, (size,), generator=gen),
        rewards=torch.randn(size, generator=gen),
        next_grids=(torch.rand(size, *GRID_SHAPE, generator=gen) < 0.2).float(),
        next_features=torch.randn(size, width, generator=gen) * 3,
        dones=(torch.rand(size, generator=gen) < 0.1).float(),
        next_mask=mask,
    )


def todays_update(cfg: DQNConfig, gen: torch.Generator) -> Callable[[int], None]:
    """n -> n of today's updates (dqn.learn) on one network."""
    online = QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned)
    target = QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned)
    sync_target(online, target)
    optimizer = make_optimizer(online, cfg)
    pool = [random_batch(gen, online.n_features, cfg.batch_size) for _ in range(POOL)]

    def run(n: int) -> None:
        for i in range(n):
            learn(online, target, optimizer, pool[i % POOL], cfg)

    return run


def stacked_update(cfg: DQNConfig, k: int, gen: torch.Generator) -> Callable[[int], None]:
    """n -> n stacked updates of a group of k networks."""
    nets = [QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned) for _ in range(k)]
    group = StackedLearner(cfg, [net.state_dict() for net in nets])
    width = nets[0].n_features
    pool = [stack_batches([random_batch(gen, width, cfg.batch_size) for _ in range(k)])[0] for _ in range(POOL)]

    def run(n: int) -> None:
        for i in range(n):
            group.learn(pool[i % POOL])

    return run


def cpu_per_call(run: Callable[[int], None], n: int) -> float:
    """CPU seconds of this process per call of run(n)'s n calls."""
    start = time.process_time()
    run(n)
    return (time.process_time() - start) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7, help="rounds of timings (default 7)")
    parser.add_argument("--groups", default="1,2,4,8,16", help="group sizes K, comma-separated")
    parser.add_argument("--keep-malloc", action="store_true", help="do not call hold_freed_memory")
    args = parser.parse_args()
    try:
        ks = [int(k) for k in args.groups.split(",")]
    except ValueError:
        parser.error(f"--groups must be comma-separated group sizes, got {args.groups!r}")
    if args.rounds < 1 or not ks or not all(1 <= k <= 64 for k in ks):
        parser.error("--rounds must be at least 1 and every group size from 1 to 64")
    torch.set_num_threads(1)
    held = False if args.keep_malloc else hold_freed_memory()
    cfg = DQNConfig()
    gen = torch.Generator().manual_seed(0)
    today = todays_update(cfg, gen)
    groups = {k: stacked_update(cfg, k, gen) for k in ks}
    today(20)  # warm up
    for k in ks:
        groups[k](max(2, 20 // k))
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread, batch {cfg.batch_size}, malloc "
          f"{'holds freed memory' if held else 'as it is'}; ms of CPU per model-update, today's | group's (ratio)")
    ratios: dict[int, list[float]] = {k: [] for k in ks}
    for r in range(args.rounds):
        line = []
        for k in ks:
            base = cpu_per_call(today, 60)
            per_model = cpu_per_call(groups[k], max(4, 60 // k)) / k
            ratios[k].append(per_model / base)
            line.append(f"K={k}: {base * 1e3:.2f} | {per_model * 1e3:.2f} ({per_model / base:.2f})")
        print(f"round {r + 1}: " + ", ".join(line), flush=True)
    print("K   ratio median (range)")
    for k in ks:
        print(f"{k:<3} {statistics.median(ratios[k]):.2f} ({min(ratios[k]):.2f}-{max(ratios[k]):.2f})")


if __name__ == "__main__":
    main()
