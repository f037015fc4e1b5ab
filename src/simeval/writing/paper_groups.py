"""One name per task group across sources, so Tables 4 and 5 put every run beside the paper's value.

The paper (and the importers of real RoboGen/BBSEA task lists, simeval.pipelines.task_texts) call the table groups "table-top";
simeval's own suites call them `table_top` (RoboGen-style) and `table` (BBSEA-style), since a group name is typed
on the command line (task_group=table_top). The tables key the paper's values by the suites' names; a run on
imported episodes is matched through `suite_group`. Every other group has the same name everywhere."""

from __future__ import annotations

SUITE_TO_PAPER = {("robogen", "table_top"): "table-top", ("bbsea", "table"): "table-top"}


def paper_group(pipeline: str, group: str) -> str:
    """The paper's name of `pipeline`'s `group` (itself when the names agree)."""
    return SUITE_TO_PAPER.get((pipeline, group), group)


def suite_group(pipeline: str, group: str) -> str:
    """Our suite's name of a group that may carry the paper's name ("table-top" -> table_top / table)."""
    back = {(p, paper): ours for (p, ours), paper in SUITE_TO_PAPER.items()}
    return back.get((pipeline, group), group)
