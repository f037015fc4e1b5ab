"""The robots the suites drive: xarm (the xArm6 of the GenSim- and RoboGen-style suites: joint control, a suction
cup or a spatula) and panda (the Franka Panda of the BBSEA-style suite). Both act in a core.world.World."""
