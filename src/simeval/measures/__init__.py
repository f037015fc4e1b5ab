"""The measurements, one folder each (after lm-evaluation-harness's one folder per task). Each holds its run
(`run.py`, callable without Hydra), its pure metric functions, its tables and figures, and its controls:

    quality/              scene alignment (1-5) and task completion (0-10) from judges; Figure 4
    agreement/            judges against human scores (Figure 3)
    text_diversity/       Eq. 1 over task descriptions (Table 3)
    dynamics_diversity/   a world model's held-out prediction error, its validity gate, the state reading (Table 4)
    generalization/       a Diffusion Policy's success on seen, varied and unseen tasks (Table 5)

Generic statistics live in simeval.stats, generic table and figure writing in simeval.writing, the learned models in
simeval.models and their training loop, checkpoints and devices in simeval.runtime."""
