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
          optimizer_state: dict[str, Any], slots: list[ReplayBatch], threads: int,
          average: QNetwork | None = None) -> None:  # fmt: skip
    """The worker's loop (the spawned process's target): online's parameters, the slots and the moving average of
    the weights (DQNConfig.weights_ema; None: off) are the training process's, shared."""
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
                losses = [learn(online, target, optimizer, b, cfg, average) for b in slots[: message[1]]]
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


class UpdateWorker:
    """The training process's handle on the update worker: submit rounds, wait for them, fetch the state."""

    def __init__(self, cfg: DQNConfig, online: QNetwork, target: QNetwork, optimizer: torch.optim.Optimizer,
                 average: QNetwork | None = None):  # fmt: skip
        online.share_memory()  # the worker updates these very tensors
        if average is not None:
            average.share_memory()
        self.slots = make_slots(cfg, online)
        ctx = torch.multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(
            target=serve,
            args=(child, cfg, online, target.state_dict(), optimizer.state_dict(), self.slots,
                  torch.get_num_threads(), average),  # fmt: skip
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

    def _send(self, message: tuple[Any, ...]) -> None:
        try:
            _send(self.conn, message)
        except (OSError, EOFError):
            raise self._death() from None

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
        self.process.join(timeout=1)
        code = self.process.exitcode
        signum = -code if code is not None and code < 0 else None
        how = f"killed by signal {signum}" if signum is not None else f"exit code {code}"
        return LearnerProcessError(f"the learner process died ({how})", signum)
