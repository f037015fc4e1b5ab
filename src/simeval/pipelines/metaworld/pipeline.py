"""Meta-World as a simeval Pipeline (simeval.pipelines.base): collection with its experts, its tasks' groups and
held-out tasks, its environment for closed-loop evaluation.

Splits (src/generalization.py): `train` = the group's tasks minus the held-out ones at new variants (every seed draws
new object and goal positions from the task's own ranges, as in the suites); `eval` = those tasks with the hand
starting away from Meta-World's start pose (`eval_variation`: {hand_init_noise: metres}; Meta-World's tasks have no
other variation than the positions every seed already draws); `heldout` = ML10's test tasks (Meta-World's own
train/test split)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, replace

from simeval.errors import UserError
from simeval.pipelines.base import Pipeline, select_tasks, split_by_heldout
from simeval.pipelines.metaworld.native import ACTION_KIND, GROUPS, MetaworldSettings

ACTION_SPACE = "metaworld"  # the policy's name for ACTION_KIND (simeval.measures.generalization.data)


class MetaworldPipeline(Pipeline):
    def __init__(self, name: str, settings: MetaworldSettings, heldout: Mapping[str, list[str]] | None = None,
                 eval_variation: Mapping | None = None) -> None:
        self.name, self.settings, self.heldout = name, settings, dict(heldout or {})
        self.eval_variation = dict(eval_variation or {})

    @classmethod
    def from_config(cls, pipeline: Mapping) -> MetaworldPipeline:
        settings = MetaworldSettings(**_native(pipeline))
        heldout = dict(pipeline.get("heldout") or {})
        for group, names in heldout.items():
            stray = sorted(set(names) - set(GROUPS.get(group, ())))
            if group not in GROUPS or stray:
                raise UserError(f"pipeline.heldout.{group}: {stray or names} not in Meta-World group {group!r} "
                                f"(groups: {', '.join(GROUPS)})")
        variation = dict(pipeline.get("eval_variation") or {})
        check_variation(variation, "pipeline.eval_variation")
        return cls(pipeline["name"], settings, heldout, variation)

    def environment_id(self):
        return {"name": self.name, **asdict(self.settings)}

    @classmethod
    def collect(cls, pipeline, *, tasks, task_group, seeds, store, record, variation, workers):
        from tqdm import tqdm

        from simeval.collect import missing_episodes, run_episodes, stored_summary, worker_count
        from simeval.episodes.store import EpisodeStore
        from simeval.pipelines.metaworld.native import CONTROL_HZ, check_rendering, collect_one
        from simeval.sim.rollout import RecordSettings

        self = cls.from_config(pipeline)
        specs, _ = self.group_and_heldout(task_group, tasks, heldout=[])  # collecting only held-out tasks is fine
        split = variation["split"]
        if split != "train":
            held = [n for n in self.heldout.get(specs[0].group, []) if n in {s.name for s in specs}]
            pairs = self.split_tasks(specs, split, held, eval_override=variation["knobs"])
            if not pairs:
                raise UserError(f"variation={split}: none of the selected Meta-World tasks is in that split")
            specs, knobs = [s for s, _ in pairs], pairs[0][1]
        else:
            knobs = dict(variation["knobs"] or {})
        check_variation(knobs, "variation.knobs")
        settings = replace(self.settings, **knobs)
        recording = RecordSettings(**{**record, "control_hz": CONTROL_HZ})  # Meta-World records at its own 80 Hz
        workers = worker_count(workers)
        check_rendering()
        epstore = EpisodeStore(store)
        varied = {"hand_init_noise": settings.hand_init_noise} if settings.hand_init_noise else {}
        todo = missing_episodes(epstore, self.name, dict.fromkeys((s.name for s in specs), varied), seeds, recording,
                                dict.fromkeys((s.name for s in specs), ACTION_KIND))
        new: list[dict] = []
        args = (str(epstore.root), asdict(settings), asdict(recording), self.name, {s.name: s.group for s in specs})
        bar = tqdm(total=len(todo), desc=f"Meta-World episodes ({workers} worker{'s' if workers > 1 else ''})",
                   unit="episode", disable=not todo)
        try:
            run_episodes(collect_one, todo, args, workers, new, bar)
        finally:
            bar.close()
        return {"new": sorted(new, key=lambda r: (r["task"], r["seed"])), "skipped": len(specs) * len(seeds) - len(todo),
                "tasks": stored_summary(epstore, self.name, {s.name: s.group for s in specs}, seeds,
                                        dict.fromkeys((s.name for s in specs), varied))}

    def group_and_heldout(self, task_group, tasks=None, heldout=None):
        if task_group == "all":
            task_group = next(iter(GROUPS))
        if task_group not in GROUPS:
            raise UserError(f"task_group={task_group}: Meta-World's groups here are {', '.join(GROUPS)}")
        return select_tasks(dict.fromkeys(GROUPS[task_group], task_group), task_group, tasks, self.heldout, heldout,
                            ACTION_SPACE, "Meta-World's")

    def split_tasks(self, specs, split, heldout, *, eval_override=None):
        variation = dict(self.eval_variation if eval_override is None else eval_override)
        check_variation(variation, "eval.variation")
        return split_by_heldout(specs, split, heldout, variation)

    def make_env(self, task, action_space, variation, image_size, cameras, max_steps):
        from simeval.pipelines.metaworld.env import MetaworldEnv

        if action_space != ACTION_SPACE:
            raise UserError(f"policy.model.action_space={action_space}: Meta-World's environment takes its own "
                            f"4-d action (policy.model.action_space=native or {ACTION_SPACE})")
        check_variation(dict(variation or {}), "eval.variation")
        return MetaworldEnv(task, replace(self.settings, **dict(variation or {})), image_size, cameras, max_steps)


def _native(pipeline: Mapping) -> dict:
    native = dict(pipeline.get("native") or {})
    unknown = sorted(set(native) - {"max_steps", "render_quality"})
    if unknown:
        raise UserError(f"pipeline.native: unknown key(s) {unknown}; Meta-World's are max_steps, render_quality")
    return native


def check_variation(variation: Mapping, key: str) -> None:
    """Meta-World's tasks vary here by {hand_init_noise: metres} only (a UserError naming `key` otherwise)."""
    unknown = sorted(set(variation) - {"hand_init_noise"})
    if unknown:
        raise UserError(f"{key}: {unknown} is not a Meta-World variation; it has hand_init_noise (metres the hand "
                        "starts away from its start pose) only: every seed already draws new object and goal positions")
    MetaworldSettings(hand_init_noise=variation.get("hand_init_noise", 0.0))
