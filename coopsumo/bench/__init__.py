"""`coopsumo bench`, the speed figures (printed, not asserted): figures (the command and the world's, the
learner's and the selection's lines), group (bench --learner's group line, issue 77), cluster (bench --cluster, a
study on a Ray cluster of one node, then two)."""
