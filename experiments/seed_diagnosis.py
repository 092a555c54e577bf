"""`coopsumo diagnose` under its old name (the study: coopsumo/studies/diagnosis.py); kept so that old command lines
still work."""

import sys

from coopsumo.studies.diagnosis import main

if __name__ == "__main__":
    sys.exit(main())
