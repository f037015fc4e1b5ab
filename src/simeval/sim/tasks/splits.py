"""The splits of the generalization protocol (paper Sec. 3.5): which tasks, with which knobs, a split rolls out.

    train    the tasks as their specs sample them (colours, counts, poses drawn per seed): the training distribution
    eval     the same tasks under each task's `variations.eval` (unseen colours, other counts, a perturbed robot
             start, ...): the varied distribution the paper tests on
    heldout  the group's held-out tasks, as their specs sample them: tasks a policy trained on the group never saw

Held-out tasks are named per group in the suite folder's `splits.yaml`, a mapping group -> {heldout: [task, ...]}:

    stacking: {heldout: [stack-blocks-by-size]}

A policy is trained on a group minus its held-out tasks; the world model (Table 4) uses every task of a group.
The seeds of each split are fixed by the `variation` config group (conf/variation/), far from the training
episodes' seeds, so two runs evaluate on the same scenes.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import yaml

from simeval.sim.tasks.spec import SpecError, TaskSpec, check_variation, variation_for

SPLITS = ("train", "eval", "heldout")
SPLITS_FILE = "splits.yaml"


def load_heldout(suite_dir: str | os.PathLike, specs: list[TaskSpec]) -> dict[str, list[str]]:
    """{group: [held-out task, ...]} from `<suite_dir>/splits.yaml` (no file: no held-out tasks), checked against
    the suite's tasks: each named task exists, belongs to that group, and a group keeps at least one task to train on."""
    path = Path(suite_dir) / SPLITS_FILE
    if not path.is_file():
        return {}
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as e:
        raise SpecError(f"cannot read {path}: {' '.join(str(e).split())}") from e  # one line, line/column kept
    groups = {s.group: [t.name for t in specs if t.group == s.group] for s in specs}
    if not isinstance(raw, dict):
        raise SpecError(f"{path}: expected a mapping group -> {{heldout: [task, ...]}}, got {type(raw).__name__}")
    out: dict[str, list[str]] = {}
    for group, entry in raw.items():
        if group not in groups:
            raise SpecError(f"{path}: unknown group '{group}'; the suite's groups: {', '.join(sorted(groups))}")
        if not isinstance(entry, dict) or set(entry) != {"heldout"} or not isinstance(entry["heldout"], list):
            raise SpecError(f"{path}: {group}: expected {{heldout: [task, ...]}}, got {entry!r}")
        names = [str(n) for n in entry["heldout"]]
        stray = [n for n in names if n not in groups[group]]
        if stray:
            raise SpecError(f"{path}: {group}.heldout names {stray}, not tasks of group {group} "
                            f"({', '.join(groups[group])})")
        if set(names) >= set(groups[group]):
            raise SpecError(f"{path}: {group}.heldout holds every task of the group; keep at least one to train on")
        out[str(group)] = names
    return out


def heldout_of(specs: list[TaskSpec], heldout: dict[str, list[str]]) -> list[str]:
    """The held-out task names among `specs`."""
    names = {n for group in heldout.values() for n in group}
    return [s.name for s in specs if s.name in names]


def split_by(specs: list, split: str, heldout: list[str], eval_split: Callable[[list], list[tuple[object, dict]]]
             ) -> list[tuple[object, dict]]:
    """[(task, variation)] that `split` rolls out among `specs`: train = the tasks not held out, unvaried; heldout =
    the held-out ones, unvaried; eval = `eval_split(the tasks not held out)`, each pipeline's own variation rule."""
    if split not in SPLITS:
        raise SpecError(f"eval.splits: split '{split}' is not one of {', '.join(SPLITS)}")
    if split == "heldout":
        return [(s, {}) for s in specs if s.name in heldout]
    trained = [s for s in specs if s.name not in heldout]
    return [(s, {}) for s in trained] if split == "train" else eval_split(trained)


def split_tasks(specs: list[TaskSpec], split: str, heldout: list[str], *,
                eval_override: dict | None = None) -> list[tuple[TaskSpec, dict]]:
    """split_by for a simeval suite: eval gives each trained task its own `variations.eval` (or `eval_override`,
    checked against the task, for every task), and leaves out a task that has none, since rolling it out unvaried
    would count the training distribution as a variation."""

    def eval_split(trained: list[TaskSpec]) -> list[tuple[TaskSpec, dict]]:
        if eval_override:
            checked = check_variation(trained, eval_override)
            return [(s, variation_for(s, checked)) for s in trained]
        return [(s, s.variations["eval"]) for s in trained if s.variations.get("eval")]

    return split_by(specs, split, heldout, eval_split)


def group_and_heldout(suite_dir: str | os.PathLike, task_group: str, tasks: list[str] | str | None = None,
                      heldout: list[str] | None = None) -> tuple[list[TaskSpec], list[str]]:
    """The tasks of `task_group` in the suite at `suite_dir` (or the named `tasks` among them) and the held-out
    ones among those: `heldout` if given, else the suite's splits.yaml. Some, not all, may be held out."""
    from simeval.sim.tasks.spec import load_suite, select_specs

    suite = load_suite(suite_dir)
    specs = select_specs(suite, None, task_group)
    if tasks:
        names = [tasks] if isinstance(tasks, str) else list(tasks)
        stray = sorted(set(names) - {s.name for s in specs})
        if stray:
            raise SpecError(f"tasks={names}: {stray} not in task_group={task_group} ({[s.name for s in specs]})")
        specs = [s for s in specs if s.name in names]
    group = [s.name for s in specs]
    held = heldout_of(specs, load_heldout(suite_dir, suite)) if heldout is None else list(heldout)
    where = f"tasks={group} of task_group={task_group}" if tasks else f"task_group={task_group} ({group})"
    stray = sorted(set(held) - set(group))
    if stray:
        raise SpecError(f"heldout_tasks={held}: {stray} not in {where}")
    if set(held) == set(group):
        raise SpecError(f"heldout_tasks={held}: must be some but not all of {where}: nothing would be left to train on")
    return specs, held
