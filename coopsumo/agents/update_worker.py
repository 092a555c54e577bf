"""The learner's gradient updates in a second process, in lockstep with the world (`coopsumo train`'s default).

The world, the decisions, the replay memory and every random draw stay in the training process; a decision
round's minibatches are drawn there, exactly as in the serial loop, and sent here. This process owns the target
network and the optimiser and updates the online network's weights in shared memory while the world runs its
next steps. The training process waits for the updates before anything reads the weights (the next decision,
a validation snapshot, a checkpoint), so every decision sees the same weights as in the serial loop: the lag is
zero rounds and the trained model is the same file, bit for bit, whatever the machine's load.

A round's minibatches travel through shared memory too (slots, one per update of a round, written only while
the worker is idle); the messages are small and pickled by value: ("update", n) answered by ("done", mean loss);
("sync",) unanswered; ("state",) answered by ("state", target and optimiser state dicts); ("stop",). A worker
that fails answers ("error", one line) and exits.
"""

from __future__ import annotations

import multiprocessing
import pickle
import signal
import sys
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

WORKER_NAME = "coopsumo-learner"
"""the worker process's name (multiprocessing sets it before the child imports this module to run serve)"""
if multiprocessing.current_process().name == WORKER_NAME:  # the worker, starting: before torch's import (seconds),
    for _stop in (signal.SIGINT, signal.SIGTERM):  # so that a Ctrl-C sent to the whole group meanwhile cannot kill it
        signal.signal(_stop, signal.SIG_IGN)

import numpy as np  # noqa: E402
import torch  # noqa: E402

from coopsumo.agents.dqn import QNetwork, learn, make_optimizer, sync_target  # noqa: E402
from coopsumo.agents.replay import GRID_SHAPE, N_ACTIONS, ReplayBatch  # noqa: E402
from coopsumo.dqn_config import DQNConfig  # noqa: E402
from coopsumo.runio import STOP_SIGNALS, children_start_deaf  # noqa: E402

GATHER_S = 0.05
"""a group's update process waits up to this long after a member's round for the other members' (a stacked step
costs as much for one member as for all: its rows are computed whether they take part or not)"""
POLL_S = 0.5
"""how often a wait checks that the worker still lives (s)"""


class LearnerProcessError(RuntimeError):
    """The update worker died or failed; the training cannot go on from its current state. signum: the signal that
    killed it (a Ctrl-C that reached it before it could ignore it), else None."""

    def __init__(self, text: str, signum: int | None = None) -> None:
        super().__init__(text)
        self.signum = signum


def make_slots(cfg: DQNConfig, online: QNetwork) -> list[ReplayBatch]:
    """One minibatch of zeros in shared memory per update of a round, shaped as the replay's samples."""
    b, width = cfg.batch_size, online.n_features

    def zeros(*shape: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        return torch.zeros(shape, dtype=dtype).share_memory_()

    return [ReplayBatch(grids=zeros(b, *GRID_SHAPE), features=zeros(b, width), actions=zeros(b, dtype=torch.int64),
                        rewards=zeros(b), next_grids=zeros(b, *GRID_SHAPE), next_features=zeros(b, width),
                        dones=zeros(b), next_mask=zeros(b, N_ACTIONS, dtype=torch.bool),
                        alphas=zeros(b) if online.conditioned else None)
            for _ in range(cfg.updates_per_learn)]  # fmt: skip


def fill(slot: ReplayBatch, batch: ReplayBatch) -> None:
    """Copy a minibatch into a slot of make_slots."""
    for name, tensor in vars(batch).items():
        if tensor is not None:
            getattr(slot, name).copy_(tensor)


def _send(conn: Connection, message: tuple[Any, ...]) -> None:
    conn.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))


def _receive(conn: Connection) -> tuple[Any, ...]:
    message: tuple[Any, ...] = pickle.loads(conn.recv_bytes())
    return message


def serve(conn: Connection, cfg: DQNConfig, online: QNetwork, target_state: dict[str, Any],
          optimizer_state: dict[str, Any], slots: list[ReplayBatch], threads: int) -> None:  # fmt: skip
    """The worker's loop (the spawned process's target): online's parameters and the slots are the training
    process's, shared."""
    # Ctrl-C and a group's SIGTERM are the training process's to handle: it asks for the state and checkpoints.
    # When it is gone, the pipe closes and this loop ends.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    torch.set_num_threads(threads)
    try:
        target = QNetwork(online.speed_scale_mps, online.dueling, online.observation, online.conditioned)
        target.load_state_dict(target_state)
        optimizer = make_optimizer(online, cfg)
        optimizer.load_state_dict(optimizer_state)
        while True:
            try:
                message = _receive(conn)
            except EOFError:
                return
            kind = message[0]
            if kind == "update":
                losses = [learn(online, target, optimizer, b, cfg) for b in slots[: message[1]]]
                _send(conn, ("done", float(np.mean(losses))))
            elif kind == "sync":
                sync_target(online, target)
            elif kind == "state":
                _send(conn, ("state", {"target": target.state_dict(), "optimizer": optimizer.state_dict()}))
            elif kind == "stop":
                return
            else:
                raise ValueError(f"unknown message {kind!r}")
    except Exception as err:  # reported to the training process in one line, which ends the training
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        try:
            _send(conn, ("error", f"{type(err).__name__}: {text}"))
        except OSError:
            pass
        sys.exit(1)


class _Handle:
    """A training's side of an update process (UpdateWorker, GroupMember): submit rounds, wait for them, fetch the
    state; how it answers and how its death shows are the subclass's."""

    conn: Connection
    slots: list[ReplayBatch]
    pending: int
    losses: list[float]

    def submit(self, batches: list[ReplayBatch]) -> None:
        """Send one round's minibatches; the worker answers with their mean loss."""
        if len(batches) > len(self.slots):
            raise ValueError(f"a round has at most {len(self.slots)} minibatches, got {len(batches)}")
        self.wait()  # the slots are the worker's while it runs
        for slot, batch in zip(self.slots, batches, strict=False):
            fill(slot, batch)
        self._send(("update", len(batches)))
        self.pending += 1

    def sync(self) -> None:
        """Copy the online weights into the target network, after every round sent so far."""
        self._send(("sync",))

    def wait(self) -> None:
        """Block until every round sent has been applied to the shared weights."""
        while self.pending:
            kind, value = self._answer()
            if kind != "done":
                raise LearnerProcessError(f"the learner process answered {kind!r} to an update")
            self.losses.append(value)
            self.pending -= 1

    def state(self) -> dict[str, Any]:
        """The target network's and the optimiser's state dicts, after every round sent so far."""
        self.wait()
        self._send(("state",))
        kind, value = self._answer()
        if kind != "state":
            raise LearnerProcessError(f"the learner process answered {kind!r} to a state request")
        return dict(value)

    def _send(self, message: tuple[Any, ...]) -> None:
        try:
            _send(self.conn, message)
        except (OSError, EOFError):
            raise self._death() from None

    def _answer(self) -> tuple[str, Any]:
        raise NotImplementedError

    def _death(self) -> LearnerProcessError:
        raise NotImplementedError


class UpdateWorker(_Handle):
    """The training process's handle on the update worker: submit rounds, wait for them, fetch the state."""

    def __init__(self, cfg: DQNConfig, online: QNetwork, target: QNetwork, optimizer: torch.optim.Optimizer):
        online.share_memory()  # the worker updates these very tensors
        self.slots = make_slots(cfg, online)
        ctx = torch.multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(
            target=serve,
            args=(child, cfg, online, target.state_dict(), optimizer.state_dict(), self.slots,
                  torch.get_num_threads()),  # fmt: skip
            name=WORKER_NAME,
            daemon=True,
        )
        # SIGINT and SIGTERM are blocked here while the child starts (a signal sent meanwhile comes the moment the
        # mask is lifted), and the child inherits the mask: blocked from its first instruction, it ignores them from
        # its import of this module on (WORKER_NAME). One that kills it all the same (a signal it was not deaf to)
        # is reported as LearnerProcessError.signum.
        with children_start_deaf(STOP_SIGNALS):
            self.process.start()
        child.close()
        self.pending = 0  # update rounds sent and not yet answered
        self.losses: list[float] = []  # mean loss of each answered round, in order

    def close(self) -> None:
        """Stop the worker (it has no state worth keeping once state() was read)."""
        if self.process.is_alive():
            try:
                self._send(("stop",))
            except LearnerProcessError:
                pass
            self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()

    def _answer(self) -> tuple[str, Any]:
        while not self.conn.poll(POLL_S):
            if not self.process.is_alive():
                raise self._death()
        try:
            kind, value = _receive(self.conn)
        except (OSError, EOFError):
            raise self._death() from None
        if kind == "error":
            raise LearnerProcessError(f"the learner process failed: {value}")
        return str(kind), value

    def _death(self) -> LearnerProcessError:
        return process_death(self.process)


def process_death(process: multiprocessing.process.BaseProcess) -> LearnerProcessError:
    """The error of an update process found dead: how it ended (the signal that killed it, or its exit code)."""
    process.join(timeout=1)
    code = process.exitcode
    signum = -code if code is not None and code < 0 else None
    how = f"killed by signal {signum}" if signum is not None else f"exit code {code}"
    return LearnerProcessError(f"the learner process died ({how})", signum)


# -- the stacked learner's update process: a group of trainings (issue 77) -----------------------------------------
@dataclass
class GroupTicket:
    """What member k of a group needs to reach its update process: its end of the pipe, and its online network and
    minibatch slots in shared memory (the process updates those very tensors)."""

    index: int
    conn: Connection
    online: QNetwork
    slots: list[ReplayBatch]


def start_group(cfg: DQNConfig, k: int) -> tuple[multiprocessing.process.BaseProcess, list[GroupTicket]]:
    """Start the update process of a group of k trainings of one learner (cfg.stacked_updates): its process and
    each member's ticket. The caller hands ticket i to member i (GroupMember); a training that never joins leaves
    its member idle. Every pipe end the process holds is closed here, so a member sees the process die as EOF."""
    ctx = torch.multiprocessing.get_context("spawn")
    onlines = [QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned) for _ in range(k)]
    for net in onlines:
        net.share_memory()
    slots = [make_slots(cfg, net) for net in onlines]
    pipes = [ctx.Pipe() for _ in range(k)]
    process = ctx.Process(target=serve_group, args=([p[1] for p in pipes], cfg, onlines, slots), name=WORKER_NAME,
                          daemon=True)  # fmt: skip
    with children_start_deaf(STOP_SIGNALS):
        process.start()
    for _, theirs in pipes:
        theirs.close()
    return process, [GroupTicket(i, pipes[i][0], onlines[i], slots[i]) for i in range(k)]


def serve_group(conns: list[Connection], cfg: DQNConfig, onlines: list[QNetwork],
                slots: list[list[ReplayBatch]]) -> None:  # fmt: skip
    """The group's update process (start_group's target): one StackedLearner for every member; whichever members
    have sent a round are updated together (a member's bits do not depend on who else is in a step), each message of
    a member handled in its order. Ends when every member has stopped or gone; a failure is told to every member."""
    from multiprocessing.connection import wait as wait_for

    from coopsumo.agents.stacked import StackedLearner, hold_freed_memory

    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    torch.set_num_threads(1)  # a member's bits are the same in any group on one thread
    hold_freed_memory()
    live, joined = dict(enumerate(conns)), set()
    try:
        learner = StackedLearner(cfg, [net.state_dict() for net in onlines])
        rounds: dict[int, int] = {}  # member -> minibatches of its round waiting (its next message waits too)
        gather_until = 0.0
        while live:
            waiting = [c for k, c in live.items() if k not in rounds]
            left = max(gather_until - time.monotonic(), 0.0) if rounds else None
            ready = wait_for(waiting, left) if waiting else []
            for k, conn in [(k, c) for k, c in live.items() if c in ready]:
                try:
                    message = _receive(conn)
                except (EOFError, OSError):
                    del live[k]
                    continue
                if message[0] == "update":
                    gather_until = gather_until if rounds else time.monotonic() + GATHER_S
                    rounds[k] = int(message[1])
                elif message[0] == "join":
                    joined.add(k)
                    _member_message(learner, k, message, onlines[k], conn)
                elif _member_message(learner, k, message, onlines[k], conn):
                    del live[k]
            if rounds and (joined & set(live) <= set(rounds) or time.monotonic() >= gather_until):
                _group_round(learner, rounds, slots, onlines, live)
                rounds = {}
    except Exception as err:  # told to every member in one line; each ends its training
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        for conn in live.values():
            try:
                _send(conn, ("error", f"{type(err).__name__}: {text}"))
            except OSError:
                pass
        sys.exit(1)


def _member_message(learner: Any, k: int, message: tuple[Any, ...], online: QNetwork, conn: Connection) -> bool:
    """Handle one message of member k other than an update; True when the member has stopped."""
    kind = message[0]
    if kind == "join":  # its weights are in `online` already; its target and optimiser come with the message
        learner.set_member(k, online.state_dict(), message[1], message[2])
    elif kind == "sync":
        learner.sync_target(_mask(learner.k, [k]))
    elif kind == "state":
        state = learner.member_state(k)
        _send(conn, ("state", {"target": state["target"], "optimizer": state["optimizer"]}))
    elif kind == "stop":
        return True
    else:
        raise ValueError(f"unknown message {kind!r}")
    return False


def _mask(k: int, members: Any) -> torch.Tensor:
    mask = torch.zeros(k, dtype=torch.bool)
    mask[list(members)] = True
    return mask


def _group_round(learner: Any, rounds: dict[int, int], slots: list[list[ReplayBatch]], onlines: list[QNetwork],
                 live: dict[int, Connection]) -> None:  # fmt: skip
    """The members' rounds (member -> its minibatches this round) as stacked steps; each member's new weights
    written into its shared network, its mean loss sent back."""
    from coopsumo.agents.stacked import stack_batches

    losses: dict[int, list[float]] = {k: [] for k in rounds}
    for i in range(max(rounds.values())):
        batch, active = stack_batches([slots[k][i] if rounds.get(k, 0) > i else None for k in range(learner.k)])
        step = learner.learn(batch, active)
        for k in rounds:
            if rounds[k] > i:
                losses[k].append(float(step[k]))
    for k in rounds:
        onlines[k].load_state_dict(learner.online_state(k))
        if k in live:
            try:
                _send(live[k], ("done", float(np.mean(losses[k]))))
            except OSError:
                del live[k]


class GroupMember(_Handle):
    """A training's handle on its group's update process (UpdateWorker's interface): join() hands the learner's
    state over and makes the shared network the learner's online network; the rest as UpdateWorker. `process`: the
    update process when this training started it (a lone training, a group of one), None in a group."""

    def __init__(self, ticket: GroupTicket, process: multiprocessing.process.BaseProcess | None = None) -> None:
        self.ticket, self.conn, self.process = ticket, ticket.conn, process
        self.slots = ticket.slots
        self.pending = 0
        self.losses: list[float] = []

    @classmethod
    def alone(cls, cfg: DQNConfig) -> GroupMember:
        """A lone training's group of one: its own update process."""
        process, tickets = start_group(cfg, 1)
        return cls(tickets[0], process)

    def join(self, learner: Any) -> None:
        """Move learner's online weights into the shared network (the learner drives with it from now on), its
        optimiser onto it, and send the target and optimiser state to the update process."""
        shared, cfg = self.ticket.online, learner.cfg
        optimizer_state = learner.optimizer.state_dict()
        with torch.no_grad():
            shared.load_state_dict(learner.online.state_dict())
        learner.online = shared
        learner.optimizer = make_optimizer(shared, cfg)
        learner.optimizer.load_state_dict(optimizer_state)
        self._send(("join", learner.target.state_dict(), optimizer_state))

    def close(self) -> None:
        """Leave the group (and stop the update process of a group of one)."""
        try:
            self._send(("stop",))
        except LearnerProcessError:
            pass
        if self.process is not None:
            self.process.join(timeout=10)
            if self.process.is_alive():
                self.process.kill()
                self.process.join()
        self.conn.close()

    def _answer(self) -> tuple[str, Any]:
        while not self.conn.poll(POLL_S):
            if self.process is not None and not self.process.is_alive():
                raise self._death()
        try:
            kind, value = _receive(self.conn)
        except (OSError, EOFError):
            raise self._death() from None
        if kind == "error":
            raise LearnerProcessError(f"the learner process failed: {value}")
        return str(kind), value

    def _death(self) -> LearnerProcessError:
        if self.process is None:
            return LearnerProcessError("the group's learner process died")
        return process_death(self.process)


def attach_updates(learner: Any, worker: bool, group: GroupTicket | None) -> None:
    """Where a training's gradient updates run: in its group's update process (group), in a group of one of its own
    (DQNConfig.stacked_updates: the stacked learner always runs in an update process), in an UpdateWorker (worker:
    --update-worker), or in the training process itself (nothing to attach)."""
    cfg = learner.cfg
    if group is not None or cfg.stacked_updates:
        member = GroupMember(group) if group is not None else GroupMember.alone(cfg)
        member.join(learner)
        learner.attach(member)
    elif worker:
        learner.attach(UpdateWorker(cfg, learner.online, learner.target, learner.optimizer))
