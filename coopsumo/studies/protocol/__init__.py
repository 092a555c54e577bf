"""The learner protocol: `coopsumo protocol` (study.py) judges learners on 10 models each against the baselines
(its catalogue of variants and profiles is data, experiments_data/*.toml, read by plan.py), its report, and
`coopsumo history` (the search's table, history.py)."""
