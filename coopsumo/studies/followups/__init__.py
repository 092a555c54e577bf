"""Studies that follow up another's results: the accident seeds and the Q-value diagnosis of a learning study's
models, the regime map of the accident's queue, the adaptive alpha fitted on a conditioned scenario II sweep, and
the robustness statistics of the learning report."""
