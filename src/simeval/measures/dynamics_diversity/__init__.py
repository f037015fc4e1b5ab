"""Dynamics diversity (paper Sec. 3.4, Table 4): `run` (train a world model on k episodes per task, score it),
`prediction` (held-out errors beside the baselines), `gate` (when a reading means nothing), `state_reading` (the
same protocol on recorded states), `table4` / `table4_heldout` / `sweep_tables` (tables and figures), `controls`
(groups whose answer is known)."""
