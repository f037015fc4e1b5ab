"""Collect oracle episodes of suite tasks into the episode store: parallel worker processes (each with its own
PyBullet client), a progress bar, resumable (episodes already in the store are skipped), deterministic per seed.
Each episode is the oracle run as a policy through the environment (simeval.sim.rollout.run_episode), stored as
the environment returned it. Failed oracle episodes are kept and flagged, as the authors' world-model data kept
them. A variation is part of an episode's identity: varied episodes are stored beside the plain ones, never over
them (simeval.episodes.store).

Workers never outlive the collector: each asks the kernel to kill it when its parent dies (Linux
PR_SET_PDEATHSIG) and also watches its parent's pid (other systems, and the moment between fork and prctl);
SIGTERM or Ctrl-C in the collector terminates the workers before it exits. A killed worker leaves at most a
temp file, which no reader takes for an episode and a later run removes."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict

from simeval.episodes.store import EpisodeStore, read_meta
from simeval.errors import UserError
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.spec import TaskSpec, check_variation, load_spec, variation_for

log = logging.getLogger(__name__)
PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
PARENT_POLL_S = 0.5


def _die_with_parent(parent: int) -> None:
    """Worker initializer: stop when the collector dies, however it dies (kill -9 included)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the collector decides
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the collector's handler, inherited through fork
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):  # no prctl: the watchdog below still stops the worker
            pass
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)  # re-parented (to init or a subreaper): the collector is gone

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _collect_one(spec_path: str, seed: int, store_root: str, settings: dict, pipeline: str,
                 variation: dict | None = None) -> dict:
    spec = load_spec(spec_path)
    t0 = time.perf_counter()
    ep = run_episode(spec, seed, RecordSettings(**settings), pipeline=pipeline,
                     variation=variation_for(spec, variation or {}))
    path = EpisodeStore(store_root).write(ep)
    return {"task": spec.name, "seed": seed, "success": ep.success, "steps": ep.n_steps,
            "seconds": time.perf_counter() - t0, "bytes": os.path.getsize(path)}


class _Stopped(SystemExit):
    """SIGTERM reached the collector: leave with the conventional status 128 + signal, workers terminated."""


def _raise_stopped(signum: int, frame) -> None:
    raise _Stopped(128 + signum)


def _run_pool(todo, workers: int, args: tuple, new: list, bar) -> None:
    on_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_stopped) if on_main_thread else None
    pool = ProcessPoolExecutor(workers, initializer=_die_with_parent, initargs=(os.getpid(),))
    try:
        futures = [pool.submit(_collect_one, s.source, seed, *args) for s, seed in todo]
        for f in as_completed(futures):
            new.append(f.result())  # a crashed episode stops the run with its error; finished ones are kept
            bar.update(1)
    except BaseException:
        for p in list((getattr(pool, "_processes", None) or {}).values()):  # no public way to stop running work
            p.kill()  # an episode cut short leaves at most a temp file, never a file a reader accepts
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    else:
        pool.shutdown()
    finally:
        if on_main_thread:
            signal.signal(signal.SIGTERM, previous)


def collect(specs: Sequence[TaskSpec], seeds: Sequence[int], store: EpisodeStore, settings: RecordSettings,
            *, pipeline: str = "gensim", workers: int = 0, progress: bool = True,
            variation: dict | None = None) -> dict:
    """Returns {"new": [per-episode dicts], "skipped": n, "tasks": {task: {episodes, success, rate, group}}}.

    `variation` ({object: {colors, count}, robot: {home_noise}}) applies to every task that has the objects
    it names; naming an object none of `specs` has is an error. An unreadable file already in the store is
    moved aside (`<name>.corrupt-<time>`, with a warning) and its episode collected again."""
    from tqdm import tqdm

    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise UserError(f"workers must be 0 (one per CPU core) or a positive number of processes, got {workers!r}")
    variation = check_variation(list(specs), variation)
    workers = workers or os.cpu_count() or 1
    store.remove_stale_temp_files()
    todo = [(s, seed) for s in specs for seed in seeds
            if not store.exists_intact(pipeline, s.name, seed, variation_for(s, variation))]
    skipped = len(specs) * len(seeds) - len(todo)
    new: list[dict] = []
    args = (str(store.root), asdict(settings), pipeline, variation)
    bar = tqdm(total=len(todo), desc=f"collecting ({workers} workers)", unit="episode", disable=not progress)
    try:
        if workers == 1 or len(todo) <= 1:
            for s, seed in todo:
                new.append(_collect_one(s.source, seed, *args))
                bar.update(1)
        else:
            _run_pool(todo, min(workers, len(todo)), args, new, bar)
    except (KeyboardInterrupt, _Stopped):
        log.warning("collection stopped: %d new episodes kept in %s; run the same command again to resume",
                    len(new), store.root)
        raise
    finally:
        bar.close()
    tasks = {}
    for s in specs:  # the summary covers the whole store for these seeds, earlier runs included
        metas = [read_meta(store.path_for(pipeline, s.name, seed, variation_for(s, variation))) for seed in seeds]
        ok = sum(m["success"] for m in metas)
        tasks[s.name] = {"group": s.group, "episodes": len(metas), "success": ok, "rate": ok / len(metas)}
    return {"new": sorted(new, key=lambda r: (r["task"], r["seed"])), "skipped": skipped, "tasks": tasks}
