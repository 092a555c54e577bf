"""Reading and showing results: loop-detector and trajectory analysis, the figures. Pure pandas,
numpy and matplotlib: no SUMO run, no torch."""
