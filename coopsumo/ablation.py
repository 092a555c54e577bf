"""`python -m coopsumo.ablation`: the same as `coopsumo learning` (coopsumo.cli)."""

import sys

from coopsumo.cli import run

if __name__ == "__main__":
    sys.exit(run("learning"))
