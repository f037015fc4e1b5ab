"""The generalization experiment (paper Sec. 4.3, Table 5) as library calls, so src/generalization.py stays thin.

    episodes_for(store, pipeline, tasks, k, val_k) -> (train episodes, val episodes): the first k episodes of each
        task by seed, and the next val_k (for the sampler check; none if the store has no more).
    checkpoint_key(...) -> a short hash of what determines the trained weights (episode files and their sizes,
        policy and training settings, seed): the checkpoint folder, so a rerun resumes or reuses the training.
    run_splits(policy, plan, ...) -> rollout rows per (split, task), cached per row in a JSON file beside the
        checkpoint (keyed by the policy's training step), so a killed evaluation resumes where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from simeval.episodes.store import EpisodeStore, read_episode
from simeval.errors import UserError
from simeval.results import atomic_write_text, dumps_strict

log = logging.getLogger(__name__)
PLAIN = re.compile(r"episode_(\d+)\.h5")


def episodes_for(store: EpisodeStore, pipeline: str, tasks: Sequence[str], k: int, val_k: int, cameras: Sequence[str]):
    if k < 1:
        raise UserError(f"episodes_per_task must be >= 1, got {k}")
    train, val, metas = [], [], []
    # the plain episodes only: a varied one (episode_<seed>.v<id>.h5, stored beside) is another distribution
    plain = {task: [p for p in store.paths(pipeline, task) if PLAIN.fullmatch(p.name)] for task in tasks}
    short = [t for t in tasks if len(plain[t]) < k]
    if short:  # name every short task at once, so the collect command given fixes them all
        counts = ", ".join(f"{t} has {len(plain[t])}" for t in short)
        raise UserError(f"store {store.root}: fewer than episodes_per_task={k} episodes ({counts}); collect them "
                        f"with: python src/collect.py pipeline={pipeline} tasks=[{','.join(short)}] "
                        f"episodes={k + val_k} store={store.root}")
    for task in tasks:
        paths = plain[task]
        paths = sorted(paths, key=lambda p: int(PLAIN.fullmatch(p.name).group(1)))  # by seed
        train += [read_episode(p, list(cameras)) for p in paths[:k]]
        val += [read_episode(p, list(cameras)) for p in paths[k : k + val_k]]
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
               progress: bool = False) -> list[dict]:
    """plan: {split: [(task, variation), ...]} (simeval.sim.splits.split_tasks); every (split, task) is rolled out
    on `seeds`, its row cached in `cache_file` so a killed evaluation resumes. Each row records its variation."""
    from simeval.models.policy.evaluate import rollout_task

    cache_file = Path(cache_file)
    cache = json.loads(cache_file.read_text()) if cache_file.is_file() else {}
    rows = []
    todo = [(s, t, dict(v or {})) for s, pairs in plan.items() for t, v in pairs]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="rollouts", unit="task")
    for split, task, var in todo:
        sampler = [policy.cfg.inference_scheduler, policy.cfg.num_inference_steps]
        key = json.dumps([policy_step, split, task, list(seeds), var, max_steps, sampler], sort_keys=True)
        if key not in cache:
            cache[key] = rollout_task(policy, task, seeds, split=split, variation=var, max_steps=max_steps)
            atomic_write_text(cache_file, dumps_strict(cache))
        rows.append({**cache[key], "variation": var})
        if bar is not None:
            bar.update(1)
            bar.set_postfix(task=task, split=split, success=cache[key]["success"]["rate"])
    if bar is not None:
        bar.close()
    return rows


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
