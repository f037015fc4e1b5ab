"""GenSim (pipeline=gensim): its task texts, read from a user's GenSim checkout (tasks.py), and simeval's GenSim-style
PyBullet suite (suite/: one YAML spec per task, solved by the generic pick-and-place oracle,
simeval.sim.experts.pick_place). GenSim's own code is the gensim_own pipeline (simeval.pipelines.gensim_own)."""
