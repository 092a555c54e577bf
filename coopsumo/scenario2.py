"""`python -m coopsumo.scenario2`, the same as `coopsumo scenario2`: the code is in coopsumo.studies.scenario2."""

import sys

from coopsumo.studies.scenario2 import main

if __name__ == "__main__":
    sys.exit(main())
