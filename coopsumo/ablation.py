"""`python -m coopsumo.ablation`, the same as `coopsumo learning`: the code is in coopsumo.studies.ablation."""

import sys

from coopsumo.studies.ablation import main

if __name__ == "__main__":
    sys.exit(main())
