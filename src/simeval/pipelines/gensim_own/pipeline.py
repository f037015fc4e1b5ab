"""GenSim's own tasks as a simeval Pipeline (simeval.pipelines.base) for the closed-loop experiments."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, replace
from pathlib import Path

from simeval.errors import UserError
from simeval.pipelines.base import Pipeline, select_tasks, split_by_heldout
from simeval.pipelines.gensim_own.env import GensimEnv
from simeval.pipelines.gensim_own.native import (
    GENSIM_EVAL_VARIATION,
    GensimSettings,
    check_checkout,
    check_settings,
    plan_tasks,
)


def check_eval_variation(variation: Mapping) -> None:
    """eval.variation for GenSim's own tasks: {mode: train | val | test, unseen_colors: true | false}, unseen
    colours only outside train mode (where GenSim draws them); a UserError naming the key otherwise."""
    valid = "GenSim's own tasks vary by {mode: train | val | test, unseen_colors: true | false} only"
    stray = sorted(set(variation) - {"mode", "unseen_colors"})
    if stray:
        raise UserError(f"eval.variation.{stray[0]}: not a variation of GenSim's own tasks; {valid}")
    if variation.get("mode", "train") not in ("train", "val", "test"):
        raise UserError(f"eval.variation.mode={variation['mode']!r}: {valid}")
    if not isinstance(variation.get("unseen_colors", False), bool):
        raise UserError(f"eval.variation.unseen_colors={variation['unseen_colors']!r}: {valid}")
    if variation.get("unseen_colors") and variation.get("mode", "train") == "train":
        raise UserError("eval.variation={unseen_colors: true} in train mode draws the train colours: unseen colours "
                        "are drawn in mode val or test, e.g. eval.variation='{mode: test, unseen_colors: true}'")


class GensimOwnPipeline(Pipeline):
    """GenSim's own tasks for the closed-loop experiments: groups from its registry (the authors' substring rule),
    held-out tasks from `heldout` (group -> names) or the command line, and GenSim's own environment with its
    pick/place action (simeval.pipelines.gensim_own.env.GensimEnv). The `eval` split is GenSim's own test-time
    variation: the same tasks in task.mode "test" with its unseen colour set drawn (GensimSettings.unseen_colors;
    tasks whose scene that leaves as it was are not rolled out again: evaluate.rollout_task)."""

    requires = ("native",)
    collect_args = " pipeline.root=<checkout>"

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
        from simeval.pipelines.gensim_own.native import collect_from_checkout

        return collect_from_checkout(pipeline.get("root"), dict(pipeline["native"]), tasks, task_group, seeds, store,
                                     dict(record), pipeline=pipeline["name"], workers=workers)

    def collect_hint(self) -> str:
        import shlex

        return f" pipeline.root={shlex.quote(str(self.settings.root))}"

    def environment_id(self):
        ident = {"name": self.name, **asdict(self.settings)}  # its checkout, rates, task mode, clock, timeouts
        if not ident["unseen_colors"]:  # as before the setting existed: cached rollouts keep their keys
            del ident["unseen_colors"]
        return ident

    def group_and_heldout(self, task_group, tasks=None, heldout=None):
        group = plan_tasks(Path(self.settings.root), None, task_group)
        return select_tasks(group, task_group, tasks, self.heldout, heldout, "pick_place", "GenSim's")

    def split_tasks(self, specs, split, heldout, *, eval_override=None):
        variation = dict(eval_override or GENSIM_EVAL_VARIATION)
        if split == "eval":
            check_eval_variation(variation)
        return split_by_heldout(specs, split, heldout, variation)

    def make_env(self, task, action_space, variation, image_size, cameras, max_steps):
        if action_space != "pick_place":
            raise UserError(f"policy.model.action_space={action_space}: GenSim's own environment takes its "
                            "pick/place action only (policy=authors_gensim or authors_gensim_cpu, or "
                            "policy.model.action_space=pick_place)")
        variation = dict(variation or {})
        settings = replace(self.settings, mode=variation.get("mode", self.settings.mode),
                           unseen_colors=variation.get("unseen_colors", self.settings.unseen_colors))
        return GensimEnv(task, settings, image_size, cameras, max_steps)
