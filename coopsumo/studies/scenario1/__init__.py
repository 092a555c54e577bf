"""Scenario I, the accident (section IV.A, Fig. 4-5): `coopsumo scenario1` (study.py), its plan, measures, report,
the paper's horizon, the sumo-gui replay and the regime map (`--regime-map`: where the
accident's queue goes, `keep` at every demand); accident_runs.py runs keep or a model through the accident for the
follow-up studies."""
