"""Single-task quality (paper Sec. 3.3): `bundle` (the task-bundle format and its checks), `run` (the judging and
the run, `run_quality`), `task_media` (what the judge saw of each task, for reports and loggers)."""
