"""result.json files -> one tidy table -> tables (CSV, Markdown, LaTeX). Nothing here reruns anything."""
