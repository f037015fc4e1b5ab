"""Controls of dynamics diversity, groups whose answer is known: `synthetic` (the committed shared/diverse control),
`random_draws` (configurations drawn from fixed seeds) and `gensim_own` (a four-task generalist against one-task
specialists on GenSim's own episodes); `python src/controls.py --help` lists the controls."""
