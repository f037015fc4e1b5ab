"""Pipelines: where a pipeline's episodes and tasks come from (base.Pipeline; registry picks one from
conf/pipeline/<name>.yaml). Kinds that run a pipeline's own software live in a folder each: gensim_own (GenSim's
tasks from a user's checkout), metaworld, gymnasium (any Gymnasium environment); importers.py and the *_format.py
modules read other pipelines' recorded data (LeRobot, robomimic, Ravens demos)."""
