"""Controls of dynamics diversity, groups whose answer is known: `synthetic` (the committed shared/diverse control)
and `random_draws` (configurations drawn from fixed seeds)."""
