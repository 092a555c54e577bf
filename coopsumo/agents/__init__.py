"""Who decides: the policies (baselines, MOBIL, the DQN), the learner, the decision interval, the
rollout loop and training. Uses coopsumo.sim; never studies or report."""
