"""RoboGen (pipeline=robogen): its task texts (tasks.py) and simeval's RoboGen-style PyBullet suite (suite/: one YAML
spec per task, articulated objects driven on end-effector deltas, simeval.sim.experts.articulation)."""
