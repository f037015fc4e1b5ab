"""Text diversity of a pipeline's task groups: tasks + an encoder in, one summary per group out."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence

import numpy as np

from simeval.measures.text_diversity.metric import DiversityInputError, diversity_summary
from simeval.pipelines.task_texts import ALL_GROUPS, TaskText, groups_of, select_group

EACH = "each"
log = logging.getLogger(__name__)


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def check_settings(n_boot, subsample_n, subsample_repeats) -> None:
    """The `metrics:` block of conf/text_diversity.yaml, checked before any work (UserError names the key)."""
    if not _is_int(n_boot) or n_boot < 10:
        raise DiversityInputError(f"metrics.n_boot must be an integer >= 10 (bootstrap resamples for the div and "
                                  f"cos_dist intervals; fewer can give no interval), got {n_boot!r}")
    if not (subsample_n is None or subsample_n == "auto" or (_is_int(subsample_n) and subsample_n >= 2)):
        raise DiversityInputError(f"metrics.subsample_n must be auto, null, or an integer >= 2 (tasks per random "
                                  f"subset), got {subsample_n!r}")
    if not _is_int(subsample_repeats) or subsample_repeats < 1:
        raise DiversityInputError(f"metrics.subsample_repeats must be an integer >= 1 (random subsets per group), "
                                  f"got {subsample_repeats!r}")


def text_diversity_by_group(
    tasks: Sequence[TaskText],
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
    check_settings(n_boot, subsample_n, subsample_repeats)
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
    elif subsample_n is not None and subsample_n > max(len(v) for v in chosen.values()):
        raise DiversityInputError(
            f"metrics.subsample_n={subsample_n} is larger than every task group here (largest: "
            f"{max(len(v) for v in chosen.values())} tasks); use auto, null, or an integer in [2, that size]")
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


def log_groups(values: dict, pipeline: str, embedding: str) -> None:
    """One line per group of a text-diversity run: its task count and Div (or why it has none)."""
    for group, v in values.items():
        log.info("%s/%s [%s] n=%d div=%s", pipeline, group, embedding, v["n"],
                 f"{v['div']:.4f}" if "div" in v else v.get("error"))
