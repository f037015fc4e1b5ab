"""The suites' scripted experts, one module per suite: gensim (Ravens-style pick-and-place oracle), robogen
(articulated-object controllers on end-effector deltas) and bbsea (the Panda's motion primitives that plans name).
sim.rollout records an episode from whichever the task's action space needs."""
