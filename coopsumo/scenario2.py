"""`python -m coopsumo.scenario2`: the same as `coopsumo scenario2` (coopsumo.cli)."""

import sys

from coopsumo.cli import run

if __name__ == "__main__":
    sys.exit(run("scenario2"))
