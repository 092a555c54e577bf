"""The experiments: cells run by one shared runner (local processes or Ray), scenario I, scenario II
and the learner ablation, with their pure statistics. Uses agents, sim and report."""
