"""`python -m coopsumo COMMAND ...`: the same as the console command `coopsumo` (coopsumo.cli)."""

import sys

from coopsumo.cli import main

sys.exit(main())
