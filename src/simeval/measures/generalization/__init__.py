"""Generalization (paper Sec. 4.3, Table 5): `run` (train a Diffusion Policy on a task group, roll it out on seen,
varied and unseen tasks), `data` (its training windows), `rollouts` (closed-loop evaluation), `random_baseline`
(uniform random actions on the same splits), `table5` (the table and its figure). The tools of
`src/generalization_tools.py`: `offline` (train where the simulator is not, score on held-out demonstrations),
`vs_random` and `eval_vs_train` (runs read against each other), `variation_probe` (which eval scenes a variation
changes)."""
