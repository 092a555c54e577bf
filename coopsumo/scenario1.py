"""`python -m coopsumo.scenario1`: the same as `coopsumo scenario1` (coopsumo.cli)."""

import sys

from coopsumo.cli import run

if __name__ == "__main__":
    sys.exit(run("scenario1"))
