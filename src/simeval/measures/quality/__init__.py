"""Single-task quality (paper Sec. 3.3): `bundle` (the task-bundle format and its checks), `run` (the judging and
the run, `run_quality`), `episode_bundles` (the episode store as quality tasks), `task_media` (what the judge saw of
each task, for reports and loggers), `figure4` (the paper's Figure 4)."""
