"""Scenario II, the alpha sweep (section IV.B, Fig. 6): `coopsumo scenario2` (study.py), its plan, measures and
report; for the lane-network profiles (full, check, paper) the gate, its report, and the redraw and merge of a
finished sweep."""
