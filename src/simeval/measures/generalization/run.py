"""The generalization experiment (paper Sec. 4.3, Table 5) as library calls, so src/generalization.py stays thin.

    episodes_for(store, pipeline, tasks, k, val_k, demonstrations) -> (train episodes, val episodes): the first k
        episodes of each task by seed, and the next val_k (for the sampler check; none if the store has no more);
        demonstrations="successful" passes over the episodes whose recorded success is False first (as GenSim's
        demos.py, which saves only completed demonstrations), "all" keeps them.
    checkpoint_key(...) -> a short hash of what determines the trained weights (episode files and their sizes,
        policy and training settings, seed): the checkpoint folder, so a rerun resumes or reuses the training.
    run_splits(policy, plan, ...) -> rollout rows per (split, task), each rollout cached by seed in a JSON file
        beside the checkpoint (keyed by the policy's training step), so a killed evaluation resumes where it stopped
        and more seeds roll out only the new ones.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simeval.episodes.store import EpisodeStore, read_episode, read_meta
from simeval.errors import UserError
from simeval.results import atomic_write_text, dumps_strict

log = logging.getLogger(__name__)
RESULT_VERSION = "1.0"  # of the generalization result.json (src/generalization.py)
PLAIN = re.compile(r"episode_(\d+)\.h5")


DEMONSTRATIONS = ("all", "successful")


def check_demonstrations(demonstrations: str) -> None:
    if demonstrations not in DEMONSTRATIONS:
        raise UserError(f"demonstrations={demonstrations!r}: must be all (every stored episode) or successful (only "
                        "those the collector recorded as successful, as GenSim's demos.py keeps)")


def _not_failed(meta: Mapping) -> bool:
    """Recorded as successful, or from a source that records no success (the authors' files: demos.py saved only
    completed demonstrations)."""
    return bool(meta["success"]) or not meta.get("success_known", True)


def demonstration_paths(store: EpisodeStore, pipeline: str, task: str, demonstrations: str = "all") -> list[Path]:
    """A task's plain episode files by seed (a varied one, episode_<seed>.v<id>.h5 stored beside, is another
    distribution), only those not failed with demonstrations=successful: episodes_for trains on the first k, and
    what follows them no policy trained at episodes_per_task=k has seen."""
    plain = sorted((p for p in store.paths(pipeline, task) if PLAIN.fullmatch(p.name)),
                   key=lambda p: int(PLAIN.fullmatch(p.name).group(1)))
    return [p for p in plain if _not_failed(read_meta(p))] if demonstrations == "successful" else plain


def episodes_for(store: EpisodeStore, pipeline: str, tasks: Sequence[str], k: int, val_k: int, cameras: Sequence[str],
                 demonstrations: str = "all", collect_args: str = ""):
    if k < 1:
        raise UserError(f"episodes_per_task must be >= 1, got {k}")
    check_demonstrations(demonstrations)
    if store.root.exists() and not store.root.is_dir():
        raise UserError(f"store={store.root}: is a file, not a folder; give the episode store's folder "
                        "(default outputs/episodes)")
    train, val, metas = [], [], []
    stored = {task: len(demonstration_paths(store, pipeline, task, "all")) for task in tasks}
    plain = {task: demonstration_paths(store, pipeline, task, demonstrations) for task in tasks}
    short = [t for t in tasks if len(plain[t]) < k]
    if short:  # name every short task at once, so the collect command given fixes them all
        tasks_arg = f"'tasks=[{','.join(short)}]'"  # quoted: unquoted brackets are a glob to the shell
        if demonstrations == "successful" and any(stored[t] for t in short):
            counts = ", ".join(f"{t} has {len(plain[t])} successful of {stored[t]}" for t in short)
            # how many episodes in all would hold k + val_k successes at each short task's own success rate, with
            # a fifth more as a margin (at the expected count, about half the time it falls short); a task with
            # nothing stored: k + val_k; none when a task has stored only failures
            needs = [k + val_k if not stored[t] else math.ceil(1.2 * (k + val_k) * stored[t] / len(plain[t]))
                     if plain[t] else None for t in short]
            more = None if None in needs else max(needs)
            # offered only where it would do: every short task has failures and at least k episodes in all
            failed_too = all(stored[t] >= k for t in short) and any(stored[t] > len(plain[t]) for t in short)
            raise UserError(f"store {store.root}: fewer than episodes_per_task={k} successful episodes ({counts}); "
                            f"collect more with python src/collect.py pipeline={pipeline}{collect_args} {tasks_arg} "
                            f"episodes={more or '<more: no stored episode of a task succeeded>'} store={store.root} "
                            "(it adds the seeds not stored yet), or lower episodes_per_task"
                            + (", or train on the failed ones too with demonstrations=all" if failed_too else ""))
        counts = ", ".join(f"{t} has {len(plain[t])}" for t in short)
        raise UserError(f"store {store.root}: fewer than episodes_per_task={k} episodes ({counts}); collect them "
                        f"(the {k} to train on" + (f" and val_episodes_per_task={val_k}" if val_k else "") + ") with: "
                        f"python src/collect.py pipeline={pipeline}{collect_args} {tasks_arg} episodes={k + val_k} "
                        f"store={store.root}")
    for task in tasks:
        paths = plain[task]
        train += [read_episode(p, list(cameras), "policy.model.cameras") for p in paths[:k]]
        val += [read_episode(p, list(cameras), "policy.model.cameras") for p in paths[k : k + val_k]]
        metas += [(str(p.relative_to(store.root)), p.stat().st_size) for p in paths[:k]]
    return train, val, metas


def checkpoint_key(metas: Sequence, policy_cfg: Mapping, train_cfg: Mapping, seed: int) -> str:
    """The folder of a training run: a hash of its data and of the settings that shape the weights (the
    inference sampler is left out, so rolling a trained policy out with another sampler reuses it)."""
    from simeval.models.diffusion_policy import SAMPLING_FIELDS

    policy = {k: v for k, v in dict(policy_cfg).items() if k not in SAMPLING_FIELDS}
    blob = json.dumps({"episodes": list(metas), "policy": policy, "train": dict(train_cfg), "seed": seed},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def run_splits(policy, plan: Mapping[str, Sequence[tuple[str, Mapping]]], seeds: Sequence[int],
               max_steps: int | None, cache_file: str | os.PathLike, policy_step: int,
               progress: bool = False, make_env=None, environment: Mapping | None = None,
               compare_starts: Mapping[str, Mapping] | None = None) -> list[dict]:
    """plan: {split: [(task, variation), ...]} (Pipeline.split_tasks); every (split, task) is rolled out on `seeds`
    (in `make_env`'s environments: the pipeline's). Each rollout is cached in `cache_file` as it ends, by seed, so a
    killed evaluation loses at most the rollout it was in and more seeds (a larger `eval.seeds`) roll out only the
    seeds not cached. A rollout depends on its seed alone (the environment's reset and the actor's noise are seeded
    by it), so seeds rolled out in different calls pool. Each row records its variation. `environment`: what else
    the rollouts depend on (the pipeline's `environment_id`, and for a policy whose cache folder is shared, as the
    chance baseline's, its settings), part of each row's key: two pipelines can name a task alike (simeval's
    GenSim-style suite and GenSim's own code).
    `compare_starts`: {task: its train variation} for the eval tasks whose seeds are compared with the train
    split's (evaluate.rollout_task's unvaried; cached rollouts too); None: every eval task the plan's train split
    has."""
    from simeval.measures.generalization.rollouts import episodes_summary, first_observations, mark_unvaried, rollout_task

    cache_file = Path(cache_file)
    cache = read_rollout_cache(cache_file)
    rows = []
    todo = [(s, t, dict(v or {})) for s, pairs in plan.items() for t, v in pairs]
    reused = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="rollouts", unit="task")
    if compare_starts is None:
        compare_starts = {t: dict(v or {}) for t, v in plan.get("train", [])}

    def save() -> None:
        atomic_write_text(cache_file, dumps_strict(cache))

    for split, task, var in todo:
        sampler = [policy.cfg.inference_scheduler, policy.cfg.num_inference_steps]
        key = rollout_key(policy_step, split, task, var, max_steps, sampler, environment)
        done = cache.setdefault(key, {"task": task, "split": split, "episodes": {}})["episodes"]
        starts = None
        if split == "eval" and task in compare_starts:
            starts = train_starts(policy, task, seeds, rows, compare_starts[task], max_steps, make_env)
        else:
            _forget_unvaried(done, seeds, split, task)
        cached = [int(s) for s in seeds if str(s) in done]
        reused += len(cached)
        if starts is not None and cached:  # rolled out before its seeds were compared, or without the train split
            row = {"episodes": [done[str(s)] for s in cached]}
            missing = [int(e["seed"]) for e in row["episodes"] if "start" not in e and not e.get("unvaried")]
            found = (first_observations(policy, task, missing, variation=var, max_steps=max_steps,
                                        make_env=make_env) if missing else {})
            marked = mark_unvaried(row, starts, found)
            if marked != row:
                done.update({str(e["seed"]): e for e in marked["episodes"]})
                save()
        left = [int(s) for s in seeds if str(s) not in done]
        if left:
            def keep(episode: Mapping, done=done) -> None:
                done[str(episode["seed"])] = dict(episode)
                save()

            rollout_task(policy, task, left, split=split, variation=var, max_steps=max_steps, make_env=make_env,
                         unvaried_if=starts, on_episode=keep)
        row = {"task": task, "split": split, **episodes_summary([done[str(s)] for s in seeds])}
        _warn_unvaried(row, var)
        rows.append({**row, "variation": var})
        if bar is not None:
            bar.update(1)
            bar.set_postfix(task=task, split=split, success=row["success"]["rate"])
    if bar is not None:
        bar.close()
    if reused:  # a resumed or repeated evaluation: say so, or its numbers look freshly rolled out
        log.info("reused %d of %d rollouts from %s (same checkpoint step, seed, variation, step limit and sampler); "
                 "delete that file to roll them out again", reused, len(todo) * len(seeds), cache_file)
    return rows


def _forget_unvaried(done: dict, seeds: Sequence[int], split: str, task: str) -> None:
    """Drop the cached rollouts of (split, task) once left out as unvaried, where this run does not compare first
    observations (a variation with a knob no first observation shows): those seeds are rolled out."""
    dropped = [s for s in seeds if done.get(str(s), {}).get("unvaried")]
    if dropped:
        log.info("split %s, %s: %d cached rollouts left out as unvaried are rolled out (their variation is "
                 "not compared by first observation)", split, task, len(dropped))
        for s in dropped:
            del done[str(s)]


def _warn_unvaried(row: Mapping, variation: Mapping) -> None:
    if row["unvaried"]:
        n, out = len(row["episodes"]), row["unvaried"]
        log.warning("split %s, %s: the variation %s left %d of %d scenes as the train split's (the same first "
                    "observation at that seed): %s", row["split"], row["task"], json.dumps(variation, sort_keys=True),
                    out, n, "none rolled out" if out == n else f"the other {n - out} rolled out")


def rollout_key(policy_step: int, split: str, task: str, variation: Mapping, max_steps: int | None,
                sampler: Sequence, environment: Mapping | None) -> str:
    """The cache key of a (split, task)'s rollouts: everything a rollout depends on but its seed."""
    return json.dumps([policy_step, split, task, dict(variation), max_steps, list(sampler), dict(environment or {})],
                      sort_keys=True, default=str)


def train_starts(policy, task: str, seeds: Sequence[int], rows: Sequence[Mapping], variation: Mapping,
                 max_steps: int | None, make_env) -> dict[int, str]:
    """{seed: first-observation digest} of `task`'s train rollouts: from its train row in `rows` where that row
    recorded them, else from resetting the train environment at each seed (a train split rolled out, and cached,
    before rollouts recorded their start)."""
    from simeval.measures.generalization.rollouts import first_observations

    for row in rows:
        if row["split"] == "train" and row["task"] == task and all("start" in e for e in row["episodes"]):
            return {e["seed"]: e["start"] for e in row["episodes"]}
    return first_observations(policy, task, seeds, variation=variation, max_steps=max_steps, make_env=make_env)


def read_rollout_cache(path: Path) -> dict:
    """The rollouts a killed or finished evaluation kept (run_splits' cache): {rollout_key: {"task", "split",
    "episodes": {seed: episode}}}; none when the file is absent. Rows of the build before per-seed caching (keyed by
    their seed list, "episodes" a list) are read as their seeds' rollouts. A file that is not such a mapping of
    rollouts is a UserError naming it and the entry (rolling out again would overwrite it)."""
    if not path.is_file():
        return {}

    def broken(what: str) -> UserError:
        return UserError(f"{path}: not a rollout cache ({what}); delete it to roll the evaluation out again")

    try:
        cache = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise broken(str(e)) from e
    if not isinstance(cache, dict):
        raise broken(f"a JSON {json_kind(cache)}, expected an object")
    out: dict = {}
    for key, row in cache.items():
        episodes = row.get("episodes") if isinstance(row, dict) else None
        if isinstance(episodes, dict):  # this build's: {seed: episode}
            pairs = list(episodes.items())
            new = key
        elif isinstance(episodes, list):  # the build before: the key holds the seed list
            try:
                step, split, task, _seeds, var, max_steps, sampler, environment = json.loads(key)
                new = rollout_key(step, split, task, var, max_steps, sampler, environment)
            except (TypeError, ValueError) as e:
                raise broken(f"entry {key[:80]!r}: not a key this product writes ({e})") from e
            pairs = [(e.get("seed") if isinstance(e, dict) else None, e) for e in episodes]
        else:
            raise broken(f"entry {key[:80]!r}: expected an object with its episodes, got "
                         f"{json_kind(episodes if isinstance(row, dict) else row)}")
        kept = out.setdefault(new, {"task": row.get("task"), "split": row.get("split"), "episodes": {}})["episodes"]
        for seed, episode in pairs:
            if problem := episode_problem(seed, episode):
                raise broken(f"entry {key[:80]!r}, seed {seed!r}: {problem}")
            kept.setdefault(str(int(seed)), episode)
    return out


def episode_problem(seed, episode) -> str | None:
    """Why a cached rollout is not one (None where it is): a seed, and either a rollout's success and progress or
    the unvaried mark."""
    if not isinstance(episode, dict):
        return f"expected an episode object, got {json_kind(episode)}"
    try:
        if isinstance(seed, bool) or int(seed) != episode.get("seed") or int(seed) < 0:
            return f"its episode records seed {episode.get('seed')!r}"
    except (TypeError, ValueError):
        return "not a seed"
    if episode.get("unvaried") is True:
        return None
    if not isinstance(episode.get("success"), bool):
        return f"success {episode.get('success')!r} is not true or false"
    progress = episode.get("progress")
    if isinstance(progress, bool) or not isinstance(progress, (int, float)) or not math.isfinite(progress):
        return f"progress {progress!r} is not a number"
    return None


def json_kind(value) -> str:
    """The JSON name of a parsed value's type, for messages."""
    return {dict: "object", list: "array", str: "string", bool: "boolean", int: "number", float: "number",
            type(None): "null"}.get(type(value), type(value).__name__)


def resolve_action_space(requested: str, specs) -> str:
    """The policy's action space: `requested`, or for "native" the one every task of `specs` is recorded in
    (joint for GenSim-style tasks, ee_delta for RoboGen-style, ee_pose for BBSEA-style); a group mixing them
    cannot be trained as one policy."""
    if requested != "native":
        return requested
    native = sorted({s.action_space for s in specs})
    if len(native) != 1:
        raise UserError(f"policy.model.action_space=native: the tasks use different action spaces "
                        f"({', '.join(f'{s.name}: {s.action_space}' for s in specs)}); name one")
    return native[0]


def names(value) -> list[str] | None:
    """A config's task list as names: None stays None, one string is one name (not its characters)."""
    return None if value is None else [value] if isinstance(value, str) else list(value)


def refuse_replaced_chance_baseline(chosen: str | None, policy_name: str) -> None:
    """policy=random chosen but another policy in the config: a debug overlay (debug=tiny sets the whole policy node)
    replaced the chance baseline, which would then train and report a policy as if it were chance. One UserError."""
    if chosen == "random" and policy_name != "random":
        raise UserError(f"policy=random is replaced by policy {policy_name!r} (debug= sets the whole policy node): "
                        "for a small chance baseline leave debug out and shrink the rollouts instead, e.g. "
                        "policy=random eval.seeds=2 eval.max_steps=40")


def eval_override(evaluation: Mapping) -> dict | None:
    """The eval section's `variation`: one variation for every eval task, or None (each task's own). An empty or
    non-mapping value is a UserError ({} would vary nothing: eval = train)."""
    given = evaluation.get("variation")
    if given is not None and not (isinstance(given, Mapping) and given):
        raise UserError(f"eval.variation={given!r}: expected a mapping of knobs, e.g. "
                        "eval.variation='{robot: {home_noise: 0.1}}' (null: each task's own eval variation)")
    return dict(given) if given else None


def check_cameras(pipeline, model: Mapping, evaluation: Mapping) -> None:
    """The policy's cameras and the video's among those the pipeline's environment offers, where it says which
    (Pipeline.cameras): a UserError before training, not after it."""
    offered = pipeline.cameras()
    if offered is None:
        return
    missing = [c for c in model["cameras"] if c not in offered]
    if missing:
        raise UserError(f"policy.model.cameras={list(model['cameras'])}: pipeline {pipeline.name}'s environment has "
                        f"cameras {', '.join(offered)}")
    if evaluation.get("videos") and evaluation.get("video_camera") not in offered:
        raise UserError(f"eval.video_camera={evaluation.get('video_camera')}: pipeline {pipeline.name}'s environment "
                        f"has cameras {', '.join(offered)} (or eval.videos=false)")


@dataclass(frozen=True)
class PolicyTraining:
    """How a policy is trained: its `model` and `train` settings (conf/policy/<preset>.yaml), its `seed`, and its
    episodes: the first `episodes_per_task` of each trained task in `store` (`demonstrations`: all | successful,
    see episodes_for) and `val_episodes_per_task` after them for the sampler check."""

    model: Mapping
    train: Mapping | None
    seed: int
    store: str
    episodes_per_task: int
    val_episodes_per_task: int
    demonstrations: str = "all"


@dataclass(frozen=True)
class GeneralizationRun:
    """What one run of src/generalization.py measures: `pipeline` (simeval.pipelines.base.Pipeline: a simeval suite
    or a pipeline's own code), its `task_group` (and `tasks` of it, `heldout_tasks`), the policy `policy_name`
    ("random": the chance baseline) and its `training`, and `evaluation`, the eval section of
    conf/generalization.yaml (splits, seeds, seed_offset, max_steps, variation, videos, video_camera,
    sampler_check)."""

    pipeline: Any
    task_group: str
    tasks: Any
    heldout_tasks: Any
    policy_name: str
    training: PolicyTraining
    evaluation: Mapping


def run_generalization(run: GeneralizationRun, *, checkpoint_dir: str, run_dir: str, logger, device,
                       progress: bool, config: Mapping | None = None) -> tuple[dict, dict]:
    """The whole experiment of src/generalization.py without Hydra: the group's tasks and held-out ones, the policy
    trained (or resumed, or reused) on the trained tasks' episodes, or the chance baseline for policy_name="random",
    every (split, task) rolled out (cached under `checkpoint_dir`), the best and worst videos (in `run_dir`).
    Returns (values, identity) for result.json; `config` is stored in the checkpoint."""
    from simeval.measures.generalization import rollouts as ev
    from simeval.measures.generalization.random_baseline import RandomActions

    pipeline, task_group, evaluation, policy_name = run.pipeline, run.task_group, run.evaluation, run.policy_name
    model, episodes_per_task, demonstrations = (run.training.model, run.training.episodes_per_task,
                                                run.training.demonstrations)
    check_demonstrations(demonstrations)  # before anything is logged or loaded
    check_cameras(pipeline, model, evaluation)
    specs, heldout = pipeline.group_and_heldout(task_group, run.tasks, names(run.heldout_tasks))
    group = [s.name for s in specs]
    trained = [t for t in group if t not in heldout]
    chance = policy_name == "random"  # the chance baseline: uniform random actions, nothing trained
    plan, compare = _rollout_plan(pipeline, specs, heldout, evaluation)
    model = dict(model)
    if chance:
        policy = RandomActions(resolve_action_space(model["action_space"], specs), model["cameras"],
                               model["image_size"])
        ckpt_dir, summary, values = f"{checkpoint_dir}/random", {"steps": 0}, {"training": None}
        settings_id = {"model": {**model, "action_space": policy.cfg.action_space}}
    else:
        data = PolicyData(pipeline.name, specs, trained, run.training, pipeline.collect_hint())
        policy, ckpt_dir, summary, values, settings_id = train_on(
            data, checkpoint_dir, bool(evaluation["sampler_check"]), logger, device, progress, config)
    seeds = range(evaluation["seed_offset"], evaluation["seed_offset"] + evaluation["seeds"])
    environment = {"pipeline": pipeline.environment_id(), **({"policy": settings_id} if chance else {})}
    rows = run_splits(policy, plan, seeds, evaluation["max_steps"], f"{ckpt_dir}/rollouts.json", summary["steps"],
                      progress=progress, make_env=pipeline.make_env, environment=environment,
                      compare_starts=compare)
    values.update(tasks=rows, splits=ev.summarize(rows))
    if evaluation["videos"] and rows and not chance:
        values["videos"] = _best_and_worst_videos(policy, rows, seeds[0], evaluation, run_dir, pipeline, logger)
    identity = {"pipeline": pipeline.name, "task_group": task_group, "tasks": group, "policy": policy_name,
                "heldout_tasks": heldout, "episodes_per_task": episodes_per_task,
                "variations": {t: v for t, v in plan.get("eval", [])},
                "eval_seeds": evaluation["seeds"], "settings": settings_id,
                # absent = the environment's own limit (as every run recorded before the key), so those still pool
                **({"eval_max_steps": evaluation["max_steps"]} if evaluation["max_steps"] is not None else {})}
    if demonstrations != "all" and not chance:  # absent = all (the runs made before the key), so those still pool
        identity["demonstrations"] = demonstrations  # runs trained on other data are not pooled into one cell
    return values, identity


def _rollout_plan(pipeline, specs, heldout: list[str], evaluation: Mapping) -> tuple[dict, dict]:
    """{split: [(task, variation)]} for the splits that have tasks, and the eval tasks whose seeds are compared
    with the train split's (see run_splits). Split names and variation keys are checked here, before training."""
    override = eval_override(evaluation)
    plan = {split: [(s.name, v) for s, v in pipeline.split_tasks(specs, split, heldout, eval_override=override)]
            for split in names(evaluation["splits"])}
    for split in [s for s, pairs in plan.items() if not pairs]:
        log.info("split %s: nothing to roll out (%s), skipped", split, "no held-out task" if split == "heldout"
                 else "no task of the group has an eval variation" if split == "eval" else "no trained task")
    plan = {split: pairs for split, pairs in plan.items() if pairs}
    pipeline.check_environment([pair for pairs in plan.values() for pair in pairs])
    compare = {}
    if plan.get("eval"):
        trained_variation = {s.name: dict(v or {}) for s, v in pipeline.split_tasks(specs, "train", heldout)}
        for task, var in plan["eval"]:
            if unseen := pipeline.unseen_knobs(var):
                log.info("split eval, %s: its variation changes what a first observation cannot show (%s): every "
                         "seed rolled out", task, ", ".join(unseen))
            elif task in trained_variation:
                compare[task] = trained_variation[task]
    return plan, compare


def _best_and_worst_videos(policy, rows: list[dict], seed: int, evaluation: Mapping, run_dir: str, pipeline,
                           logger) -> dict:
    from simeval.measures.generalization import rollouts as ev

    videos = ev.best_and_worst_videos(policy, rows, seed, evaluation["max_steps"], evaluation["video_camera"],
                                      run_dir, pipeline.make_env)
    for which, video in videos.items():
        _, split, task = Path(video).stem.split("_", 2)  # videos/<which>_<split>_<task>.mp4
        logger.log_video(f"rollout/{which}", video, caption=(
            f"{which} task of the {split} split: {task} (seed {seed}, camera {evaluation['video_camera']})"))
    return videos


@dataclass(frozen=True)
class PolicyData:
    """What a policy trains on: `pipeline`'s episodes of the `trained` tasks (of `specs`), read and trained as
    `training` says; `collect_args`: what a too-few-episodes error's collect command needs."""

    pipeline: str
    specs: Sequence
    trained: list[str]
    training: PolicyTraining
    collect_args: str = ""


def training_data(d: PolicyData):
    """What train_on trains on: (PolicyConfig, TrainSettings, PolicyDataset of the trained tasks' episodes, those
    episodes, the validation episodes, the episode files and sizes that key the checkpoint)."""
    from simeval.models.diffusion_policy import PolicyConfig, TrainSettings
    from simeval.measures.generalization.data import PolicyDataset

    t = d.training
    pcfg = PolicyConfig.from_mapping({**t.model, "action_space": resolve_action_space(t.model["action_space"],
                                                                                      d.specs)})
    settings = TrainSettings(**dict(t.train or {}), seed=t.seed)
    train_eps, val_eps, metas = episodes_for(EpisodeStore(t.store), d.pipeline, d.trained, t.episodes_per_task,
                                             t.val_episodes_per_task, pcfg.cameras, t.demonstrations, d.collect_args)
    data = PolicyDataset(train_eps, pcfg.action_space, pcfg.cameras, pcfg.image_size, pcfg.horizon, pcfg.n_obs_steps)
    return pcfg, settings, data, train_eps, val_eps, metas


def train_on(d: PolicyData, checkpoint_dir: str, sampler_check: bool, logger, device, progress: bool,
             config: Mapping | None):
    """The policy trained (or resumed, or reused) on `d`, with the sampler check: (policy, checkpoint folder,
    training summary, values so far, the settings that identify it)."""
    from simeval.models.diffusion_policy import DiffusionPolicy, train_policy
    from simeval.measures.generalization import rollouts as ev
    from simeval.measures.generalization.data import PolicyDataset

    pcfg, settings, data, train_eps, val_eps, metas = training_data(d)
    seed, trained, demonstrations = d.training.seed, d.trained, d.training.demonstrations
    ckpt_dir = f"{checkpoint_dir}/{checkpoint_key(metas, vars(pcfg), vars(settings), seed)}"
    fresh = DiffusionPolicy(pcfg, data.state_dim, data.action_dim, data.stats(), seed=seed)
    policy, summary = train_policy(fresh, data, settings, ckpt_dir, logger.log_metrics,
                                   extra={"config": dict(config or {})}, progress=progress, device=device)
    failed = sum(1 for e in train_eps if e.success_known and not e.success)
    values = {"training": {**summary, "checkpoint": f"{ckpt_dir}/last.ckpt", "trained_tasks": trained,
                           "windows": len(data), "demonstrations": {"kept": demonstrations, "episodes": len(train_eps),
                                                                    "failed": failed}}}
    if sampler_check and val_eps:
        val = PolicyDataset(val_eps, pcfg.action_space, pcfg.cameras, pcfg.image_size, pcfg.horizon, pcfg.n_obs_steps)
        values["sampler_check"] = ev.sampler_action_error(policy, val, {
            "ddpm": ("ddpm", pcfg.num_train_timesteps), "ddim": ("ddim", pcfg.num_inference_steps)})
    return policy, ckpt_dir, summary, values, {"model": vars(pcfg), "train": vars(settings)}


def log_splits(values: Mapping) -> None:
    """One line per evaluated split: success k/n with its interval, and mean progress."""
    for split, v in values["splits"].items():
        sr = v["success"]
        unvaried = (f"  ({v['unvaried']} left out: {'its' if v['unvaried'] == 1 else 'their'} scene was the train "
                    "split's)" if v.get("unvaried") else "")
        if not sr["n"]:
            log.info("%-10s nothing rolled out%s", split, unvaried)
            continue
        progress = "unknown" if v["mean_progress"] is None else f"{v['mean_progress']:.2f}"
        log.info("%-10s success %d/%d = %.2f [%.2f, %.2f]  progress %s%s", split, sr["k"], sr["n"], sr["rate"],
                 *sr["ci"], progress, unvaried)
