"""The learning study: `coopsumo learning` (study.py), the learner ablation's chain of variants and its alpha
response (plan.py), its report, and the finished trainings a learning folder holds (models.py)."""
