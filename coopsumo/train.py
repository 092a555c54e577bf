"""`python -m coopsumo.train`, the same as `coopsumo train`: the code is in coopsumo.agents.train."""

import sys

from coopsumo.agents.train import main

if __name__ == "__main__":
    sys.exit(main())
