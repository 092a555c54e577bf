"""`python -m coopsumo.scenario2`: the alpha sweep (section IV.B). The code is in coopsumo.studies.scenario2."""

import sys

from coopsumo.studies.scenario2 import main

if __name__ == "__main__":
    sys.exit(main())
