"""Your own pipeline's task texts (pipeline=custom): a YAML, JSON or CSV file of tasks by group (tasks.py)."""
