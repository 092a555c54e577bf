"""Studies that follow up another's results: the accident seeds of a learning study's models and the robustness
statistics of the learning report (the regime map of the accident's queue is scenario I's `--regime-map`)."""
