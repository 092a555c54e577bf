"""The regime map under its old name: `coopsumo regime-map` (`make regime-map`) is the command, its study
coopsumo/studies/regime_map.py. Kept so that old command lines and callers of `run` still work."""

import sys

from coopsumo.studies.regime_map import main
from coopsumo.studies.regime_map import run_study as run

__all__ = ["main", "run"]

if __name__ == "__main__":
    sys.exit(main())
