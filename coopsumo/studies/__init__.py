"""The experiments, one folder per study on one engine: engine/ (the runner, cell records, run folders, trainings,
the model store, statistics), scenario1/, scenario2/, learning/ (the learner ablation), protocol/ (judging learners,
and the search's history) and followups/ (the studies that follow up a learning or scenario study: accident seeds,
the regime map, robustness). A study's folder holds its command (study.py), plan,
measures and report; nothing in engine/ reaches into a study. Uses agents, sim and report."""
