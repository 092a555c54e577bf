"""The experiments, one folder per study on one engine: engine/ (the runner, cell records, run folders, trainings,
the model store, statistics), scenario1/ (with the regime map of the accident's queue), scenario2/ and protocol/
(judging learners: the ablation, alpha responses, and the search's history). A study's folder holds its command
(study.py), plan, measures and report; nothing in engine/ reaches into a study. Uses agents, sim and report."""
