"""The suites' scripted experts, one module per way of acting, whichever suite's task uses it: pick_place (the
generic Ravens-style oracle: goals -> pick-and-place or push primitives, GenSim-style tasks), articulation
(closed-loop articulated-object controllers on end-effector deltas, RoboGen-style tasks) and plan (the Panda's motion
primitives that a task's `plan` names, BBSEA-style tasks). sim.rollout records an episode from whichever the task's
action space needs."""
