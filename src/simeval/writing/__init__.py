"""Generic writing, below the measurements: result.json files -> one tidy table (`tidy`) -> tables (CSV, Markdown,
LaTeX: `tables`) and figures (`figures`), and the paper's own numbers (`paper_values`, `paper_groups`,
`paper_human_eval.json`). Nothing here reruns anything; what reads every measurement at once is simeval.report."""
