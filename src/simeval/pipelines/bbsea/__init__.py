"""BBSEA (pipeline=bbsea): its task texts (tasks.py) and simeval's BBSEA-style PyBullet suite (suite/: one YAML spec
per task, a Franka Panda acting through a task's plan of primitives, simeval.sim.experts.plan)."""
