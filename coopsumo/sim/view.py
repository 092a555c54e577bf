"""What sumo-gui shows of the controller: one colour per vehicle state (pure numpy, no SUMO).

States, in order of precedence: held by the accident (will stop at the bottleneck), lane change
under way, slower than SLOW_MPS, cruising.
"""

from __future__ import annotations

import numpy as np

CRUISING, SLOW, CHANGING, HELD = 0, 1, 2, 3
STATE_NAMES = ("cruising", "slower than 5 m/s", "lane change under way", "held by the accident")
STATE_RGBA = np.array(
    [
        (235, 235, 235, 255),  # cruising: light grey
        (255, 150, 0, 255),  # slow: orange
        (0, 170, 255, 255),  # changing lanes: blue
        (230, 0, 90, 255),  # held: crimson
    ],
    dtype=np.int64,
)
"""colour (r, g, b, alpha; 0-255) of each state, indexed by state"""
STATE_COLOUR_NAMES = ("light grey", "orange", "blue", "crimson")
SLOW_MPS = 5.0
"""below this speed (m/s) a vehicle counts as slow (the stop-and-go threshold of scenario I)"""
ACCIDENT_ACTIVE_RGBA = (255, 0, 0, 255)
"""the bottleneck marker while vehicles may be held there"""
ACCIDENT_IDLE_RGBA = (150, 150, 150, 255)
"""the bottleneck marker before and after the accident window"""
VIEW_UPSTREAM_M = 200.0
"""in the accident scenario sumo-gui starts zoomed on this much road upstream of the bottleneck (m)"""
VIEW_DOWNSTREAM_M = 40.0
"""... and this much downstream (m)"""


def vehicle_states(speed: np.ndarray, changing: np.ndarray, held: np.ndarray, slow_mps: float = SLOW_MPS) -> np.ndarray:
    """State per vehicle (int8): held beats changing beats slow beats cruising. speed in m/s."""
    states = np.full(len(speed), CRUISING, np.int8)
    states[np.asarray(speed) < slow_mps] = SLOW
    states[np.asarray(changing, bool)] = CHANGING
    states[np.asarray(held, bool)] = HELD
    return states
