"""Collect oracle episodes of suite tasks into the episode store: parallel worker processes (each with its own
PyBullet client), a progress bar, resumable (episodes already in the store are skipped), deterministic per seed.
Failed oracle episodes are kept and flagged, as the authors' world-model data kept them."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict

from simeval.episodes.store import EpisodeStore, read_meta
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.spec import TaskSpec, load_spec


def _collect_one(spec_path: str, seed: int, store_root: str, settings: dict, pipeline: str,
                 variation: dict | None = None) -> dict:
    spec = load_spec(spec_path)
    t0 = time.perf_counter()
    known = {o.name for o in spec.objects} | {"robot"}
    own = {k: v for k, v in (variation or {}).items() if k in known}  # each task takes the knobs it has
    ep = run_episode(spec, seed, RecordSettings(**settings), pipeline=pipeline, variation=own)
    path = EpisodeStore(store_root).write(ep)
    return {"task": spec.name, "seed": seed, "success": ep.success, "steps": ep.n_steps,
            "seconds": time.perf_counter() - t0, "bytes": os.path.getsize(path)}


def collect(specs: Sequence[TaskSpec], seeds: Sequence[int], store: EpisodeStore, settings: RecordSettings,
            *, pipeline: str = "gensim", workers: int = 0, progress: bool = True,
            variation: dict | None = None) -> dict:
    """Returns {"new": [per-episode dicts], "skipped": n, "tasks": {task: {episodes, success, rate, group}}}."""
    from tqdm import tqdm

    workers = workers or os.cpu_count() or 1
    store.remove_stale_temp_files()
    todo = [(s, seed) for s in specs for seed in seeds if not store.exists(pipeline, s.name, seed)]
    skipped = len(specs) * len(seeds) - len(todo)
    new: list[dict] = []
    bar = tqdm(total=len(todo), desc=f"collecting ({workers} workers)", unit="episode", disable=not progress)
    if workers == 1:
        for s, seed in todo:
            new.append(_collect_one(s.source, seed, str(store.root), asdict(settings), pipeline, variation))
            bar.update(1)
    else:
        with ProcessPoolExecutor(workers) as pool:
            futures = [pool.submit(_collect_one, s.source, seed, str(store.root), asdict(settings), pipeline,
                                   variation) for s, seed in todo]
            for f in as_completed(futures):
                new.append(f.result())  # a crashed episode stops the run with its error; finished ones are kept
                bar.update(1)
    bar.close()
    tasks = {}
    for s in specs:  # the summary covers the whole store for these seeds, earlier runs included
        metas = [read_meta(store.path_for(pipeline, s.name, seed)) for seed in seeds]
        ok = sum(m["success"] for m in metas)
        tasks[s.name] = {"group": s.group, "episodes": len(metas), "success": ok, "rate": ok / len(metas)}
    return {"new": sorted(new, key=lambda r: (r["task"], r["seed"])), "skipped": skipped, "tasks": tasks}
