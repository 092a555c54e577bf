"""`python -m coopsumo.train`: the same as `coopsumo train` (coopsumo.cli)."""

import sys

from coopsumo.cli import run

if __name__ == "__main__":
    sys.exit(run("train"))
