"""Studies that follow up another's results: the accident seeds of a learning study's models, the regime map of the
accident's queue, and the robustness statistics of the learning report."""
