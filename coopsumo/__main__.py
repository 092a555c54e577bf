"""`python -m coopsumo` lists the commands."""

print("coopsumo commands: python -m coopsumo.simulate | coopsumo.train | coopsumo.scenario1 | coopsumo.scenario2 | "
      "coopsumo.ablation | coopsumo.bench (each with --help)")  # fmt: skip
