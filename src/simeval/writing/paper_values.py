"""The paper's numbers that our tables and figures show beside ours, keyed by our suites' group names
(simeval.writing.paper_groups maps the paper's "Table-Top" to `table_top` / `table`).

TABLE4: world-model eval error (paper Table 4), pipeline -> group -> {training episodes per task: error}, the
    posterior image error summed over 128x128x3 pixels in [0, 1] (per pixel: value / TABLE4_PIXELS).
TABLE5: imitation-learning result per (pipeline, group) (paper Table 5): GenSim reports the step-wise reward (1.0 =
    success), RoboGen and BBSEA a success rate (TABLE5_MEANING).
"""

from __future__ import annotations

TABLE4 = {
    "gensim": {"stacking": {10: 115.0, 20: 67.2, 40: 24.5}, "placement": {10: 245.0, 20: 177.6, 40: 29.5},
               "piles": {10: 68.3, 20: 47.6, 40: 14.5}, "assembling": {10: 105.4, 20: 64.3, 40: 29.6}},
    "robogen": {"table_top": {10: 16.2, 20: 10.9, 40: 6.4}, "ground": {10: 45.8, 20: 28.6, 40: 14.5}},
    "bbsea": {"drawer": {10: 402.4, 20: 287.0, 40: 69.6}, "table": {10: 561.6, 20: 296.6, 40: 87.9}},
}
TABLE4_EPISODES = (10, 20, 40)
TABLE4_PIXELS = 128 * 128 * 3

TABLE5 = {("gensim", "stacking"): 0.15, ("gensim", "placement"): 0.32, ("gensim", "piles"): 0.2,
          ("gensim", "assembling"): 0.08, ("robogen", "table_top"): 0.0, ("robogen", "ground"): 0.0,
          ("bbsea", "table"): 0.0, ("bbsea", "drawer"): 0.0}
TABLE5_MEANING = "paper: GenSim step-wise reward (1.0 = success), RoboGen/BBSEA success rate"
# pipelines that run, with the pipeline's own code, the tasks the paper measured under another name: their rows sit
# beside the paper's numbers of that pipeline (pipeline=gensim_own: GenSim's own tasks, which the authors ran)
PAPER_PIPELINE = {"gensim_own": "gensim"}


def paper_table5(pipeline: str, group: str) -> float | None:
    """The paper's Table 5 value of our (pipeline, group), or None where the paper has none."""
    return TABLE5.get((PAPER_PIPELINE.get(pipeline, pipeline), group))
