"""`python -m coopsumo.scenario1`, the same as `coopsumo scenario1`: the code is in coopsumo.studies.scenario1."""

import sys

from coopsumo.studies.scenario1 import main

if __name__ == "__main__":
    sys.exit(main())
