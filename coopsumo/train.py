"""`python -m coopsumo.train`: train the shared DQN in free flow. The code is in coopsumo.agents.train."""

import sys

from coopsumo.agents.train import main

if __name__ == "__main__":
    sys.exit(main())
