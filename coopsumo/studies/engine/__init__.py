"""What every study runs on: cells run by one shared runner (local processes or Ray) with their records, run
folders and their checks, trainings and the model store, and the statistics. Imports no study."""
