"""Where a trained model's CPU goes, process by process: a lone training of the learner before issue 77, or a group
of K trainings of issue 77's learner (stacked updates, the two-stage selection), as `coopsumo bench --learner`'s
group line trains them (the default learner, its selection scaled to the run).

    .venv/bin/python experiments/group_processes.py K [STEPS]     # K = 0: the lone training; STEPS: 18,000

Every process below this one is read from /proc every 0.1 s (its user and system CPU time, its command line, its
parent); prints one JSON line: the wall time, this process's own CPU, each role's processes' CPU s (the world's
process of a lone training is this one; a group's members and its update process are this one's children, each
member's validation process a grandchild), and the CPU s a model. A process's last 0.1 s may be missed. Measure on
a quiet machine: on 2 cores every process beside it changes the figures (docs/performance.md, 2026-12-03).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

HZ = os.sysconf("SC_CLK_TCK")


def descendants(root: int) -> list[int]:
    """Every process below `root`, from /proc's parent links."""
    children: dict[int, list[int]] = {}
    for name in os.listdir("/proc"):
        if name.isdigit() and (stat := _stat(int(name))) is not None:
            children.setdefault(stat[1], []).append(int(name))
    found, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def _stat(pid: int) -> tuple[float, int, str] | None:
    """(CPU s, parent pid, command line) of pid, or None when it has gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        cmd = Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
    except OSError:
        return None
    fields = text[text.rfind(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / HZ, int(fields[1]), cmd


def _role(me: int, parent: int, cmd: str) -> str:
    if "coopsumo.agents.selection" in cmd:
        return "validation"
    if parent == me:
        return "member or update process"
    return "other (netconvert, git)"


def main(k: int, steps: int) -> int:
    import torch

    from coopsumo.agents.group import train_group
    from coopsumo.agents.train import train
    from coopsumo.bench.figures import scaled_selection
    from coopsumo.bench.group import before_and_after

    torch.set_num_threads(1)
    before, after = before_and_after(scaled_selection(steps))
    me, seen, stop = os.getpid(), {}, threading.Event()

    def sample() -> None:
        while not stop.is_set():
            for pid in descendants(me):
                if (stat := _stat(pid)) is not None:  # an ended process (a zombie) has an empty command line
                    seen[pid] = stat if stat[2].strip() or pid not in seen else (stat[0], stat[1], seen[pid][2])
            time.sleep(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    with tempfile.TemporaryDirectory() as tmp:
        start, own = time.perf_counter(), time.process_time()
        if k == 0:
            train(before, Path(tmp) / "lone", progress=False, learner_process=True)
        else:
            cfgs = [replace(after, sim=replace(after.sim, seed=after.sim.seed + i)) for i in range(k)]
            failed = [r for r in train_group(cfgs, [Path(tmp) / f"m{i}" for i in range(k)]) if r.error]
            if failed:
                sys.exit(f"a member failed: {failed[0].error}")
        wall, own = time.perf_counter() - start, time.process_time() - own
    stop.set()
    sampler.join()
    roles: dict[str, list[float]] = {}
    for cpu, parent, cmd in seen.values():
        roles.setdefault(_role(me, parent, cmd), []).append(round(cpu, 1))
    total = own + sum(cpu for cpu, _, _ in seen.values())
    print(json.dumps({"k": k, "steps": steps, "wall_s": round(wall, 1), "own_cpu_s": round(own, 1),
                      "roles": {r: sorted(v) for r, v in roles.items()},
                      "cpu_s_per_model": round(total / max(k, 1), 1)}))  # fmt: skip
    return 0


if __name__ == "__main__":  # the members are spawned: they import this file again
    words = sys.argv[1:]
    if len(words) not in (1, 2) or not all(a.isascii() and a.isdigit() for a in words) or int(words[0]) > 16 \
            or (len(words) == 2 and not 1 <= int(words[1]) <= 10_000_000):  # fmt: skip
        print("usage: experiments/group_processes.py K [STEPS]   (K = 0: a lone training; K at most 16, STEPS from 1 "
              "to 10,000,000)", file=sys.stderr)  # fmt: skip
        sys.exit(2)
    from coopsumo.runio import run_cli

    sys.exit(run_cli("group_processes", lambda: main(int(words[0]), int(words[1]) if len(words) == 2 else 18_000)))
