"""`python -m coopsumo.bench`, the spelling of `coopsumo bench` as a module."""

import sys

from coopsumo.bench.figures import main

if __name__ == "__main__":
    sys.exit(main())
