"""What the closed-loop experiments need of a pipeline, whatever runs its tasks: its task groups and held-out tasks,
the tasks and variations each evaluation split rolls out, and an environment for a task. Two kinds so far:
simeval's own suites (`SuitePipeline`, PyBullet re-creations) and a pipeline's own code
(simeval.pipelines.gensim_own.pipeline.GensimOwnPipeline: GenSim's tasks run from a checkout).
simeval.pipelines.registry picks the class from a `conf/pipeline/<name>.yaml` (pipeline_class) and builds one
(pipeline_from_config). Collection goes through the class too (`Pipeline.collect`), so src/collect.py knows no
pipeline by name: a new pipeline is a class here, its `kind` in the registry and its yaml.

Task objects only need `.name`, `.group` and `.action_space` (simeval.sim.tasks.spec.TaskSpec has them; `NativeTask` for
tasks simeval has no spec of)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from simeval.errors import UserError


def load_target(target: str, key: str):
    """The object a `module.name` path names (a config's _target_ or factory), importable from the user's
    PYTHONPATH; a UserError naming `key` and why it cannot be had (no such module, no such name in it)."""
    import importlib

    module, _, name = str(target).rpartition(".")
    if not module:
        raise UserError(f"{key}={target}: expected module.name, e.g. my_sim.make_env")
    try:
        found = importlib.import_module(module)
    except ImportError as e:
        raise UserError(f"{key}={target}: cannot import {module} ({e}); put its folder on PYTHONPATH") from None
    if not hasattr(found, name):
        raise UserError(f"{key}={target}: {module} ({getattr(found, '__file__', '?')}) has no {name!r}") from None
    return getattr(found, name)


@dataclass(frozen=True)
class NativeTask:
    """A task a pipeline's own code builds (GenSim's registry, Meta-World): simeval knows it by name, group and the
    action space its episodes are recorded in, which is what a generalization run reads of a TaskSpec."""
    name: str
    group: str
    action_space: str  # as TaskSpec.action_space: the space its episodes are recorded in ("pick_place" here)


class Pipeline(ABC):
    name: str  # the pipeline's name (conf/pipeline/<name>.yaml's `name`), set by from_config
    requires: tuple[str, ...] = ()  # keys its pipeline config must set (the registry checks them first)
    collect_args: str = ""  # what its src/collect.py command needs beyond pipeline= (said where episodes are missing)

    def collect_hint(self) -> str:
        """`collect_args` with this pipeline's own values where it has them (a missing-episodes error's command)."""
        return self.collect_args

    @classmethod
    @abstractmethod
    def from_config(cls, pipeline: Mapping) -> Pipeline:
        """The pipeline a `conf/pipeline/<name>.yaml` (as a plain mapping) describes; a UserError when it is unusable."""

    @classmethod
    @abstractmethod
    def collect(cls, pipeline: Mapping, *, tasks, task_group: str, seeds: Sequence[int], store, record: Mapping,
                variation: Mapping, workers: int) -> dict:
        """src/collect.py's work for this pipeline: oracle episodes of the selected tasks for `seeds` into `store`,
        recorded with `record` (conf/collect.yaml's record.*) under `variation` (variation.split, variation.knobs).
        Returns {new: [...], skipped, tasks: {task: {group, episodes, success, rate, ...}}, failed?: [...]}.
        A classmethod, so a collector checks its own settings in its own order before anything else is built."""

    @abstractmethod
    def group_and_heldout(self, task_group: str, tasks=None, heldout: list[str] | None = None) -> tuple[list, list[str]]:
        """The tasks of `task_group` (or the named `tasks` among them) and the held-out names among them."""

    @abstractmethod
    def split_tasks(self, specs: list, split: str, heldout: list[str], *, eval_override: dict | None = None
                    ) -> list[tuple[object, dict]]:
        """[(task, variation)] that evaluation split `split` (train | eval | heldout) rolls out."""

    def unseen_knobs(self, variation: Mapping) -> list[str]:
        """The knobs of `variation` that change what a first observation cannot show (friction, masses): the eval
        split leaves out a seed whose first observation is its train rollout's (the variation changed nothing the
        policy sees), which is right only for a variation without such knobs; one with them is rolled out on every
        seed. None by default; a pipeline with dynamics knobs names them."""
        return []

    def check_environment(self, pairs: list[tuple[str, dict]]) -> None:
        """Make (and reset) the environment of each (task, variation) before a policy trains, where that is cheap
        enough to be worth it: a UserError then rather than after training. Nothing by default."""

    def cameras(self) -> list[str] | None:
        """The camera names its environment offers (checked before a policy trains), or None where any recorded
        one can be rendered."""
        return None

    def environment_id(self) -> dict:
        """What this pipeline's environments depend on besides a rollout's task, variation, action space, frames and
        step limit: part of the key under which a rollout is cached (a cached rollout is reused only where it
        matches). A pipeline with settings of its own adds them."""
        return {"name": self.name}

    @abstractmethod
    def make_env(self, task: str, action_space: str, variation: Mapping, image_size: Sequence[int],
                 cameras: Sequence[str], max_steps: int | None):
        """A Gymnasium env of `task` observed as simeval's (obs["rgb"][camera], obs["state"]; info["success"],
        info["progress"])."""


def select_tasks(group: Mapping[str, str], task_group: str, tasks, configured: Mapping[str, list[str]],
                 heldout: list[str] | None, action_space: str, source: str) -> tuple[list[NativeTask], list[str]]:
    """Pipeline.group_and_heldout for a pipeline's own tasks: `group` ({name: group}) narrowed to `tasks`, and the
    held-out ones: `heldout` as given, else `configured[task_group]` (its config's list, which may name tasks not
    selected). `source` names the task registry in messages ("GenSim's", "Meta-World's")."""
    specs = [NativeTask(n, g, action_space) for n, g in group.items()]
    if tasks:
        names = [tasks] if isinstance(tasks, str) else list(tasks)
        stray = sorted(set(names) - set(group))
        if stray:
            raise UserError(f"tasks={names}: {stray} not in {source} task_group={task_group} ({sorted(group)})")
        specs = [s for s in specs if s.name in names]
    names = [s.name for s in specs]
    held = [h for h in configured.get(task_group, []) if h in names] if heldout is None else list(heldout)
    stray = sorted(set(held) - set(names))
    if stray:
        raise UserError(f"heldout_tasks={held}: {stray} not in the selected tasks {names}")
    if held and set(held) == set(names):
        raise UserError(f"heldout_tasks={held}: must be some but not all of {names}: nothing would be left to "
                        "train on")
    return specs, held


def split_by_heldout(specs: list, split: str, heldout: list[str], variation: Mapping) -> list[tuple[object, dict]]:
    """Pipeline.split_tasks for a pipeline whose `eval` split is its trained tasks under one `variation` (none: an
    empty split): train = the tasks not held out, heldout = the held-out ones."""
    from simeval.sim.tasks.splits import split_by  # the suite's spec parser stays unloaded until a split is asked

    return split_by(specs, split, heldout, lambda trained: [(s, dict(variation)) for s in trained] if variation else [])


class SuitePipeline(Pipeline):
    """simeval's own PyBullet suite at `suite_dir` (simeval.sim): specs, splits.yaml, make_env."""

    requires = ("suite",)

    def __init__(self, name: str, suite_dir: Path) -> None:
        self.name, self.suite_dir = name, Path(suite_dir)

    @classmethod
    def from_config(cls, pipeline):
        from simeval.sim.tasks.spec import suite_dir

        return cls(pipeline["name"], suite_dir(pipeline["suite"]))

    @classmethod
    def collect(cls, pipeline, *, tasks, task_group, seeds, store, record, variation, workers):
        from simeval.collect import collect, plan_suite
        from simeval.episodes.store import EpisodeStore
        from simeval.sim.rollout import RecordSettings

        suite_dir = cls.from_config(pipeline).suite_dir
        specs, common, per_task = plan_suite(suite_dir, tasks, task_group, variation["split"], variation["knobs"])
        return collect(specs, seeds, EpisodeStore(store), RecordSettings(**record), pipeline=pipeline["name"],
                       workers=workers, variation=common, task_variations=per_task)

    def environment_id(self):
        return {"name": self.name, "suite": self.suite_dir.name}

    def unseen_knobs(self, variation):
        from simeval.sim.tasks.spec import UNSEEN_KNOBS

        return [f"{name}.{knob}" for name, knobs in dict(variation or {}).items() if isinstance(knobs, Mapping)
                for knob in knobs if knob in UNSEEN_KNOBS]

    def group_and_heldout(self, task_group, tasks=None, heldout=None):
        from simeval.sim.tasks.splits import group_and_heldout

        return group_and_heldout(self.suite_dir, task_group, tasks, heldout)

    def split_tasks(self, specs, split, heldout, *, eval_override=None):
        from simeval.sim.tasks.splits import split_tasks

        return split_tasks(specs, split, heldout, eval_override=eval_override)

    def make_env(self, task, action_space, variation, image_size, cameras, max_steps):
        from simeval.sim import make_env

        kwargs = {"max_steps": max_steps} if max_steps else {}
        return make_env(task, action_space=action_space, variation=dict(variation or {}),
                        image_size=tuple(image_size), cameras=tuple(cameras), **kwargs)

