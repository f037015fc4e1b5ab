"""Text diversity of a pipeline's task groups: tasks + an encoder in, one summary per group out."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from simeval.metrics.text_diversity import DiversityInputError, diversity_summary
from simeval.tasks import ALL_GROUPS, Task, groups_of, select_group

EACH = "each"


def text_diversity_by_group(
    tasks: Sequence[Task],
    encode: Callable[[list[str]], np.ndarray],
    task_group: str = EACH,
    *,
    n_boot: int = 1000,
    subsample_n: int | str | None = "auto",
    subsample_repeats: int = 50,
    seed: int = 0,
) -> dict[str, dict]:
    """{group: diversity_summary} for one group, `all`, or (`each`) every group and `all`.

    With `each`, a group whose value is undefined (fewer than 2 tasks, a non-positive mean similarity) is
    recorded as {"n": .., "error": reason} so the other groups still report; a single requested group raises.
    `subsample_n="auto"` uses the smallest group's size so every group is also compared at a common N.
    """
    tasks = list(tasks)
    if not tasks:
        raise DiversityInputError("no tasks loaded")
    names = groups_of(tasks) + [ALL_GROUPS] if task_group == EACH else [task_group]
    chosen = {g: select_group(tasks, g) for g in names}
    distinct = list(dict.fromkeys(t.text for t in tasks))
    vectors = dict(zip(distinct, encode(distinct)))  # each distinct text embedded once
    if subsample_n == "auto":
        sizes = [len(v) for v in chosen.values() if len(v) >= 2]
        subsample_n = min(sizes) if sizes else None
    elif subsample_n is not None and not isinstance(subsample_n, int):
        raise ValueError(f"metrics.subsample_n must be auto, an int or null, got {subsample_n!r}")
    out: dict[str, dict] = {}
    for group, members in chosen.items():
        group_texts = [t.text for t in members]
        try:
            out[group] = diversity_summary(
                np.stack([vectors[t] for t in group_texts]), group_texts, n_boot=n_boot,
                subsample_n=subsample_n if subsample_n and subsample_n <= len(members) else None,
                subsample_repeats=subsample_repeats, seed=seed,
            )
        except DiversityInputError as e:
            if task_group != EACH:
                raise DiversityInputError(f"task_group '{group}': {e}") from e
            out[group] = {"n": len(members), "error": str(e)}
    return out
