"""`python -m coopsumo.train`, the same as `coopsumo train`: the code is in coopsumo.agents.train_cli."""

import sys

from coopsumo.errors import USAGE_EXIT
from coopsumo.runio import run_interruptible, working_folder_problem


def main(argv: list[str] | None = None) -> int:
    """coopsumo.agents.train_cli.main, imported only once the working folder is known to exist (from a deleted one,
    torch cannot be loaded: Intel oneMKL ends the process); a Ctrl-C while it is imported is one line, as in
    `coopsumo train` (runio.run_interruptible)."""
    return run_interruptible(lambda: _main(argv), lambda: "train", whole_process=argv is None)


def _main(argv: list[str] | None) -> int:
    if problem := working_folder_problem():
        print(f"train: error: {problem}", file=sys.stderr)
        return USAGE_EXIT
    from coopsumo.agents.train_cli import main as train_main

    return train_main(argv)


if __name__ == "__main__":
    sys.exit(main())
