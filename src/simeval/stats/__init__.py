"""Statistics shared by the measurements, as pure functions: `bootstrap` (percentile bootstrap, jackknife),
`intervals` (Wilson intervals of success rates), `resample` (two-level bootstrap of held-out error ratios)."""
