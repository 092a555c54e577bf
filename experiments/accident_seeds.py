"""`coopsumo accident-seeds` under its old name (the study: coopsumo/studies/accident_seeds.py); kept so that old
command lines still work."""

import sys

from coopsumo.studies.accident_seeds import main

if __name__ == "__main__":
    sys.exit(main())
