"""GenSim's own tasks as a simeval Pipeline (simeval.pipelines.base) for the closed-loop experiments."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from simeval.errors import UserError
from simeval.pipelines.base import NativeTask, Pipeline
from simeval.pipelines.gensim.env import GensimEnv
from simeval.pipelines.gensim.native import (
    GENSIM_EVAL_VARIATION,
    GensimSettings,
    check_checkout,
    check_settings,
    plan_tasks,
)


class GensimOwnPipeline(Pipeline):
    """GenSim's own tasks for the closed-loop experiments: groups from its registry (the authors' substring rule),
    held-out tasks from `heldout` (group -> names) or the command line, and GenSim's own environment with its
    pick/place action (simeval.pipelines.gensim.env.GensimEnv). The `eval` split is GenSim's own test-time
    variation: the same tasks in task.mode "test" (its held-out colours, where a task has them)."""

    requires = ("native",)

    def __init__(self, name: str, settings: GensimSettings, heldout: Mapping[str, list[str]] | None = None) -> None:
        self.name, self.settings, self.heldout = name, settings, dict(heldout or {})

    @classmethod
    def from_config(cls, pipeline: Mapping) -> GensimOwnPipeline:
        root = check_checkout(pipeline.get("root"))
        settings = GensimSettings(root=str(root), **dict(pipeline["native"]))
        check_settings(settings, settings.control_hz)
        return cls(pipeline["name"], settings, pipeline.get("heldout"))

    @classmethod
    def collect(cls, pipeline, *, tasks, task_group, seeds, store, record, variation, workers):
        from simeval.pipelines.gensim.native import collect_from_checkout

        return collect_from_checkout(pipeline.get("root"), dict(pipeline["native"]), tasks, task_group, seeds, store,
                                     dict(record), pipeline=pipeline["name"], workers=workers)

    def group_and_heldout(self, task_group, tasks=None, heldout=None):
        group = plan_tasks(Path(self.settings.root), None, task_group)
        specs = [NativeTask(n, g, "pick_place") for n, g in group.items()]
        if tasks:
            names = [tasks] if isinstance(tasks, str) else list(tasks)
            stray = sorted(set(names) - set(group))
            if stray:
                raise UserError(f"tasks={names}: {stray} not in GenSim's task_group={task_group} ({sorted(group)})")
            specs = [s for s in specs if s.name in names]
        names = [s.name for s in specs]
        held = list(self.heldout.get(task_group, [])) if heldout is None else list(heldout)
        held = [h for h in held if h in names] if heldout is None else held  # a config list may name other tasks
        stray = sorted(set(held) - set(names))
        if stray:
            raise UserError(f"heldout_tasks={held}: {stray} not in the selected tasks {names}")
        if held and set(held) == set(names):
            raise UserError(f"heldout_tasks={held}: must be some but not all of {names}: nothing would be left to "
                            "train on")
        return specs, held

    def split_tasks(self, specs, split, heldout, *, eval_override=None):
        if split not in ("train", "eval", "heldout"):
            raise UserError(f"eval.splits: split '{split}' is not one of train, eval, heldout")
        if split == "heldout":
            return [(s, {}) for s in specs if s.name in heldout]
        trained = [s for s in specs if s.name not in heldout]
        if split == "train":
            return [(s, {}) for s in trained]
        variation = dict(eval_override or GENSIM_EVAL_VARIATION)
        if set(variation) - {"mode"} or variation.get("mode") not in ("train", "val", "test"):
            raise UserError(f"eval.variation={variation}: GenSim's own tasks vary by {{mode: train | val | test}} "
                            "(task.mode: its seen / unseen colour sets) only")
        return [(s, variation) for s in trained]

    def make_env(self, task, action_space, variation, image_size, cameras, max_steps):
        if action_space != "pick_place":
            raise UserError(f"policy.model.action_space={action_space}: GenSim's own environment takes its "
                            "pick/place action only (policy=authors_gensim or authors_gensim_cpu, or "
                            "policy.model.action_space=pick_place)")
        mode = dict(variation or {}).get("mode", self.settings.mode)
        return GensimEnv(task, replace(self.settings, mode=mode), image_size, cameras, max_steps)
