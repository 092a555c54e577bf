"""`coopsumo <command> [options]`: the console command (also `python -m coopsumo <command>`).

Each command's options and `main(argv)` live in the command's own module (COMMANDS); this module only picks
the command, applies the options shared by all (--nets-dir) and hands it the rest of the command line.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

# Nothing else is imported here (not even typing): the console command imports this module before main runs, and a
# Ctrl-C is one line from main's first instruction on. The command line's machinery is imported where it is used.
TYPE_CHECKING = False  # typing.TYPE_CHECKING's idiom without typing: True for mypy only
if TYPE_CHECKING:
    from coopsumo.runio import Parser

S = "coopsumo.studies."
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("coopsumo.simulate", "run one simulation (free flow or the accident) with any policy"),
    "train": ("coopsumo.agents.train_cli", "train the shared DQN on drawn demands and accidents, evaluate it"),
    "scenario1": (S + "scenario1.study", "the accident study of section IV.A, across demands"),
    "scenario2": (S + "scenario2.study", "the alpha sweep of section IV.B (Fig. 6)"),
    "protocol": (S + "protocol.study", "judge learners (the ablation, alpha responses): models vs baselines"),
    "history": (S + "protocol.history", "print the learner search's table from the protocol studies' records"),
    "models": (S + "engine.store_listing", "list the model store: every trained model and whether it is usable"),
    "bench": ("coopsumo.bench.figures", "speed figures (printed, not asserted)"),
}
"""command -> (module holding its parser and main(argv), one line of what it does)"""


def build_parser() -> Parser:
    import argparse

    from coopsumo import __version__
    from coopsumo.paths import NETS_ENV
    from coopsumo.runio import Parser

    table = "\n".join(f"  {name:10s} {text}" for name, (_, text) in COMMANDS.items())
    p = Parser(
        prog="coopsumo",
        description="Cooperative lane changing via deep reinforcement learning, on Eclipse SUMO.",
        epilog=f"commands:\n{table}\n\n`coopsumo COMMAND --help` lists a command's options with their defaults.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"coopsumo {__version__}")
    p.add_argument("--nets-dir", default=None, metavar="DIR",
                   help=f"folder the SUMO networks are built into (default: ${NETS_ENV} if set, else sumo_nets/ "
                        "of a source checkout, else $XDG_CACHE_HOME/coopsumo/sumo_nets)")  # fmt: skip
    p.add_argument("command", choices=tuple(COMMANDS), nargs="?", metavar="COMMAND",
                   help="one of: " + ", ".join(COMMANDS))  # fmt: skip
    p.add_argument("args", nargs="*", metavar="OPTIONS", help="the command's own options (COMMAND --help)")
    return p


def split_argv(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """(coopsumo's own options and the command, the command's options): the split is at the first word that is
    not an option of coopsumo or the value of --nets-dir."""
    i = 0
    while i < len(argv) and argv[i].startswith("-"):
        i += 2 if argv[i] == "--nets-dir" else 1
    return list(argv[: i + 1]), list(argv[i + 1 :])


def _out_of(argv: Sequence[str]) -> str | None:
    """The value of --out in a command's options (--out X or --out=X), or None."""
    for i, word in enumerate(argv):
        if word == "--out" and i + 1 < len(argv):
            return argv[i + 1]
        if word.startswith("--out="):
            return word[len("--out=") :]
    return None


def command_of(argv: Sequence[str]) -> str:
    """The command a command line names (the name its lines start with), else "coopsumo"."""
    own, _ = split_argv(argv)
    return own[-1] if own and own[-1] in COMMANDS else "coopsumo"


class Terminated(KeyboardInterrupt):
    """SIGTERM before runio takes it over (main's first instructions): one line, exit code 143, as a Ctrl-C there."""

    signum = 15


def _terminated(signum: int, frame: object) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    """Run `coopsumo [--nets-dir DIR] COMMAND [options]`; returns the command's exit code. A Ctrl-C (SIGINT) or a
    SIGTERM at any moment, from this first instruction on (the command's imports included), ends it in one line and
    exit code 128 + the signal; run as the process's command (argv None: the console command, `python -m coopsumo`),
    one while Python exits is ignored (runio.run_interruptible). Issue 82, probe 7, I15: a SIGTERM before runio took
    it ended the process without a line."""
    import _signal  # built in: no import, no time; SIGTERM raises Terminated until run_interruptible takes it

    before = _signal.signal(_signal.SIGTERM, _terminated)
    try:  # Python's own KeyboardInterrupt until run_interruptible takes SIGINT (while runio is imported)
        from coopsumo.runio import run_interruptible

        return run_interruptible(lambda: _main(sys.argv[1:] if argv is None else argv),
                                 lambda: command_of(sys.argv[1:] if argv is None else argv),
                                 whole_process=argv is None)  # fmt: skip
    except KeyboardInterrupt as err:
        fresh = "\n" if getattr(sys.stderr, "mid_line", False) else ""  # runio.fresh_line, if runio was imported
        print(f"{fresh}{command_of(sys.argv[1:] if argv is None else argv)}: interrupted", file=sys.stderr)
        return 128 + getattr(err, "signum", 2)
    finally:
        if argv is not None:  # called in a process of its own (a test): its SIGTERM as it was
            _signal.signal(_signal.SIGTERM, before)


def _main(argv: Sequence[str]) -> int:
    import importlib
    import os
    from pathlib import Path

    from coopsumo.errors import UsageError
    from coopsumo.owners import nets_problem
    from coopsumo.paths import NETS_ENV, library_env_problem, nets_dir_problem
    from coopsumo.runio import working_folder_problem

    parser = build_parser()
    own, rest = split_argv(argv)
    args = parser.parse_args(own)
    if args.command is None:
        parser.print_usage(sys.stderr)
        print("coopsumo: error: name a command: " + ", ".join(COMMANDS), file=sys.stderr)
        return 2
    if problem := working_folder_problem():  # before a command is imported: torch cannot be loaded from there
        parser.error(problem)
    if problem := library_env_problem():  # before a command is imported: it may import matplotlib or tqdm
        parser.error(problem)
    if args.nets_dir is not None and (problem := nets_dir_problem(args.nets_dir) or nets_problem(args.nets_dir)):
        parser.error(f"--nets-dir {problem}")  # SUMO reads them there; not a folder a study, a run or the store owns
    if args.nets_dir is not None and (out := _out_of(rest)) is not None:
        nets, target = Path(args.nets_dir).expanduser().resolve(), Path(out).expanduser().resolve()
        if nets == target or nets.is_relative_to(target):
            parser.error(f"--nets-dir {args.nets_dir} lies in --out {out}: the networks would fill the output folder; "
                         "pick a networks folder outside it")  # fmt: skip
    if args.nets_dir is not None:
        # read by sim.network when a network is built, here and in the study's worker processes
        os.environ[NETS_ENV] = str(Path(args.nets_dir).expanduser().resolve())
    try:
        module = importlib.import_module(COMMANDS[args.command][0])
    except UsageError as err:  # data the command reads when imported refused (the protocol's learners.toml)
        print(f"coopsumo {args.command}: error: {err}", file=sys.stderr)
        return 2
    if args.command == "bench":  # bench reports no file error of its own: a full temporary folder is one line too
        from coopsumo.runio import run_cli

        return run_cli("bench", lambda: int(module.main(rest)))
    return int(module.main(rest))


if __name__ == "__main__":
    sys.exit(main())
