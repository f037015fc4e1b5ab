"""Task specifications: spec (parse, check and sample a suite's YAML task), goals (the success predicates a spec
names) and splits (train / eval / held-out per suite and group)."""
