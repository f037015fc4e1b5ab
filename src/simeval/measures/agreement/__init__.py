"""Agreement of judges with human scores (paper Figure 3): `metric` (Pearson, MAE, their ratio and the rest, as pure
functions), `run` (reading the scores, per table, pipeline and judge), `figure3`."""
