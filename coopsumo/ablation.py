"""`python -m coopsumo.ablation`: the learner ablation and alpha response. The code is in coopsumo.studies.ablation."""

import sys

from coopsumo.studies.ablation import main

if __name__ == "__main__":
    sys.exit(main())
