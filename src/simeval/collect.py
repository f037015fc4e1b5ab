"""Collect oracle episodes of suite tasks into the episode store: parallel worker processes (each with its own
PyBullet client), a progress bar, resumable (episodes already in the store are skipped), deterministic per seed.
Each episode is the oracle run as a policy through the environment (simeval.sim.rollout.run_episode), stored as
the environment returned it. Failed oracle episodes are kept and flagged, as the authors' world-model data kept
them. A variation is part of an episode's identity: varied episodes are stored beside the plain ones, never over
them (simeval.episodes.store).

Workers never outlive the collector: each asks the kernel to kill it when its parent dies (Linux
PR_SET_PDEATHSIG) and also watches its parent's pid (other systems, and the moment between fork and prctl);
SIGTERM or Ctrl-C in the collector terminates the workers before it exits. A killed worker leaves at most a
temp file, which no reader takes for an episode and a later run removes. A worker killed alone (e.g. by the
out-of-memory killer) stops the run with WorkerDied, naming the episode it was recording; the finished
episodes are kept and the same command resumes.

Resuming checks how the stored episodes were recorded (cameras, image and scene-view sizes, control rate,
action space, read from each file): an episode made with other `settings` is never kept as if it matched, nor
silently overwritten; the run stops with a UserError naming the file, the stored value and the requested one."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict
from pathlib import Path

from simeval.episodes.store import EpisodeStore, read_meta, read_recording
from simeval.errors import UserError, require_folder
from simeval.sim.action_spaces import EE_DELTA_KIND, EE_POSE_HZ, EE_POSE_KIND, JOINT_KIND
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import TaskSpec, check_variation, load_spec, variation_for

log = logging.getLogger(__name__)
PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
PARENT_POLL_S = 0.5
_started = None  # in a worker: the queue on which it announces (pid, task, seed) before each episode


class WorkerDied(RuntimeError):
    """A worker process died without finishing its episode (killed by a signal, e.g. the out-of-memory killer).
    Not a UserError: nothing on the command line was wrong; src/collect.py exits 1 with this one line."""


def _die_with_parent(parent: int, started=None) -> None:
    """Worker initializer: stop when the collector dies, however it dies (kill -9 included)."""
    global _started
    _started = started
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
                 variations: dict[str, dict] | None = None) -> dict:
    """Record and store one episode; `variations` maps task names to their (checked) variations."""
    spec = load_spec(spec_path)
    announce_episode(spec.name, seed)
    t0 = time.perf_counter()
    ep = run_episode(spec, seed, RecordSettings(**settings), pipeline=pipeline,
                     variation=(variations or {}).get(spec.name, {}))
    path = EpisodeStore(store_root).write(ep)
    return {"task": spec.name, "seed": seed, "success": ep.success, "steps": ep.n_steps,
            "seconds": time.perf_counter() - t0, "bytes": os.path.getsize(path)}


def announce_episode(task: str, seed: int) -> None:
    """In a worker of run_episodes: which episode it starts, so a worker that dies is named by its episode."""
    if _started is not None:
        _started.put((os.getpid(), task, seed))


def worker_count(workers) -> int:
    """collect's `workers=`: 0 (one per CPU core) or a positive number of processes, as a count; else a UserError."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise UserError(f"workers must be 0 (one per CPU core) or a positive number of processes, got {workers!r}")
    return workers or os.cpu_count() or 1


class _Stopped(SystemExit):
    """SIGTERM reached the collector: leave with the conventional status 128 + signal, workers terminated."""


def _raise_stopped(signum: int, frame) -> None:
    raise _Stopped(128 + signum)


def _dead_worker_message(procs: dict, started, new: list, store_root: str) -> str:
    """Which episode the dead worker was recording: the last one it announced on `started`."""
    by_pid: dict[int, tuple[str, int]] = {}
    while not started.empty():
        pid, task, seed = started.get()
        by_pid[pid] = (task, seed)
    deadline = time.monotonic() + 2.0  # the pool sees a dead worker's pipes close a moment before it can be reaped
    for p in procs.values():
        p.join(max(0.0, deadline - time.monotonic()))
    # the pool's own thread reaps workers too: when it wins the race, our waitpid sees no child and exitcode stays
    # None until that thread stores the status, a moment later (seen under load: the SIGKILLed worker went missing)
    while any(p.exitcode is None for p in procs.values()) and time.monotonic() < deadline:
        time.sleep(0.05)
    dead = [(p.pid, p.exitcode) for p in procs.values() if p.exitcode not in (None, 0)]
    # once the pool is broken it terminates the other workers (SIGTERM): the one that died first is another
    dead.sort(key=lambda d: d[1] == -signal.SIGTERM)
    how, episode = "", None
    if dead:
        pid, code = dead[0]
        how = f" (pid {pid}, killed by signal {-code}; the out-of-memory killer?)" if code < 0 else \
            f" (pid {pid}, exit status {code})"
        episode = by_pid.get(pid)
    finished = {(r["task"], r["seed"]) for r in new}
    if episode is None:
        which = "while recording an episode"
    elif episode in finished:
        which = f"between episodes (after {episode[0]} seed {episode[1]})"
    else:
        which = f"while recording {episode[0]} seed {episode[1]}"
    kept = f"the {len(new)} episode{'' if len(new) == 1 else 's'} finished in this run are kept"
    return f"a collection worker died {which}{how}; {kept} in {store_root}: run the same command again to resume"


def run_episodes(one, jobs, args: tuple, workers: int, new: list, bar) -> None:
    """`one(key, seed, *args) -> dict` for each (key, seed) of `jobs`, appended to `new` as each finishes: here when
    workers == 1 or there is one job, else in `workers` processes that die with the caller (kill -9 included).
    `one` is a module-level function that calls announce_episode first; args[0] is the store's root (named in the
    message when a worker dies). A failed episode stops the run with its error; finished ones stay in `new`."""
    if workers == 1 or len(jobs) <= 1:
        for key, seed in jobs:
            new.append(one(key, seed, *args))
            bar.update(1)
    else:
        _run_pool(one, jobs, min(workers, len(jobs)), args, new, bar)


def _run_pool(one, jobs, workers: int, args: tuple, new: list, bar) -> None:
    import multiprocessing as mp

    on_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_stopped) if on_main_thread else None
    ctx = mp.get_context()
    started = ctx.SimpleQueue()
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_die_with_parent,
                               initargs=(os.getpid(), started))
    try:
        futures = [pool.submit(one, key, seed, *args) for key, seed in jobs]
        procs = dict(getattr(pool, "_processes", None) or {})  # a broken pool forgets its processes: keep them
        for f in as_completed(futures):
            try:
                new.append(f.result())  # a crashed episode stops the run with its error; finished ones are kept
            except BrokenProcessPool as e:  # a worker was killed (kill -9, the OOM killer): say which, no traceback
                procs.update(getattr(pool, "_processes", None) or {})
                raise WorkerDied(_dead_worker_message(procs, started, new, args[0])) from e
            bar.update(1)
    except BaseException:
        for p in list((getattr(pool, "_processes", None) or {}).values()):  # no public way to stop running work
            p.kill()  # an episode cut short leaves at most a temp file, never a file a reader accepts
        manager = getattr(pool, "_executor_manager_thread", None)
        pool.shutdown(wait=False, cancel_futures=True)
        if manager is not None:
            # the pool's thread closes its wake-up pipe as it ends, and Python 3.11's exit hook writes to that pipe
            # without a lock: leaving while the thread still runs can print a "Bad file descriptor" traceback at exit
            manager.join(timeout=10)
        raise
    else:
        pool.shutdown()
    finally:
        if on_main_thread:
            signal.signal(signal.SIGTERM, previous)


def check_recorded_like(path: Path, settings: RecordSettings, kind: str = JOINT_KIND) -> None:
    """An episode already stored counts as done only if it was recorded as `settings` asks (in the task's
    action-space `kind`). ee_pose tasks (the BBSEA suite) record at their own 4 Hz, whatever record.control_hz."""
    stored = read_recording(path)
    wanted = {"record.cameras": sorted(settings.cameras), "record.image_size": list(settings.image_size),
              "record.scene_view_size": list(settings.scene_view_size),
              "record.control_hz": EE_POSE_HZ if kind == EE_POSE_KIND else float(settings.control_hz),
              "action_space": kind}
    for key, want in wanted.items():
        have = stored[key]
        if key == "record.scene_view_size" and have is None:
            continue  # episodes stored without scene views (not made by this collector) are not judged by them
        if key == "record.image_size" and have is None and not stored["record.cameras"]:
            continue  # no camera recorded, so no frame size to compare (the camera lists are compared above)
        if have != want:
            show = (lambda v: f"{v:g}") if key == "record.control_hz" and have is not None else repr
            raise UserError(f"{path} was recorded with {key}={show(have)}, this run asks for {show(want)}; stored "
                            f"episodes are kept, not overwritten: give another store= for these settings (or "
                            f"collect with the stored ones)")


def missing_episodes(store: EpisodeStore, pipeline: str, variation_of: dict[str, dict | None], seeds: Sequence[int],
                     recorded_as: RecordSettings, kind_of: dict[str, str]) -> list[tuple[str, int]]:
    """The (task, seed) pairs of `variation_of`'s tasks ({task: its variation, or None}) that `store` lacks, after
    making the store's folder (one line naming `store` where it cannot be one) and clearing temp files left by a
    killed run. An episode already stored counts as done only if recorded as `recorded_as` asks in its task's
    action-space kind (`kind_of`, check_recorded_like); an unreadable one is moved aside and collected again (the
    store's exists_intact). Every collector (the suites, GenSim's own code, Meta-World) resumes through here."""
    require_folder("store", store.root)
    store.remove_stale_temp_files()
    todo = []
    for task, varied in variation_of.items():
        for seed in seeds:
            if store.exists_intact(pipeline, task, seed, varied):
                check_recorded_like(store.path_for(pipeline, task, seed, varied), recorded_as, kind_of[task])
            else:
                todo.append((task, seed))
    return todo


def stored_summary(store: EpisodeStore, pipeline: str, group_of: dict[str, str], seeds: Sequence[int],
                   variation_of: dict[str, dict | None] | None = None, failed: Sequence[dict] | None = None) -> dict:
    """{task: {group, episodes, success, rate[, failed]}} over the episodes of `seeds` in the store (earlier runs'
    included): what a collector reports at its end. `failed` ({task, seed, ...} of episodes a collector reported
    instead of stopping: GenSim's code) adds each task's failed seeds; rate is None for a task with none stored."""
    out = {}
    for task, group in group_of.items():
        varied = (variation_of or {}).get(task)
        metas = [read_meta(store.path_for(pipeline, task, seed, varied)) for seed in seeds
                 if store.exists(pipeline, task, seed, varied)]
        ok = sum(m["success"] for m in metas)
        out[task] = {"group": group, "episodes": len(metas), "success": ok, "rate": ok / len(metas) if metas else None}
        if failed is not None:
            out[task]["failed"] = sorted(f["seed"] for f in failed if f["task"] == task)
    return out


def collect(specs: Sequence[TaskSpec], seeds: Sequence[int], store: EpisodeStore, settings: RecordSettings,
            *, pipeline: str = "gensim", workers: int = 0, progress: bool = True,
            variation: dict | None = None, task_variations: dict[str, dict] | None = None) -> dict:
    """Returns {"new": [per-episode dicts], "skipped": n, "tasks": {task: {episodes, success, rate, group}}}.

    `variation` ({object: {colors, count}, robot: {home_noise}}) applies to every task that has the objects
    it names; naming an object none of `specs` has is an error. `task_variations` ({task: variation}, e.g. each
    task's own `eval` variation, simeval.sim.tasks.splits) gives tasks their own instead; give one or the other.
    An unreadable file already in the store is moved aside (`<name>.corrupt-<time>`, with a warning) and its
    episode collected again."""
    from tqdm import tqdm

    workers = worker_count(workers)
    if variation and task_variations:
        raise UserError("give a variation for every task or one per task (task_variations), not both")
    variation = check_variation(list(specs), variation)
    var_of = {s.name: check_variation([s], (task_variations or {}).get(s.name)) if task_variations
              else variation_for(s, variation) for s in specs}
    bad_seed = next((s for s in seeds if isinstance(s, bool) or not isinstance(s, int) or s < 0), None)
    if bad_seed is not None:
        raise UserError(f"seeds must be whole numbers >= 0 (seed_offset >= 0), got seed {bad_seed!r}")
    kinds = {"ee_delta": EE_DELTA_KIND, "ee_pose": EE_POSE_KIND}
    todo = missing_episodes(store, pipeline, var_of, seeds, settings,
                            {s.name: kinds.get(s.action_space, JOINT_KIND) for s in specs})
    skipped = len(specs) * len(seeds) - len(todo)
    new: list[dict] = []
    args = (str(store.root), asdict(settings), pipeline, var_of)
    source_of = {s.name: s.source for s in specs}
    plural = "" if workers == 1 else "s"
    bar = tqdm(total=len(todo), desc=f"collecting ({workers} worker{plural})", unit="episode", disable=not progress)
    try:
        run_episodes(_collect_one, [(source_of[name], seed) for name, seed in todo], args, workers, new, bar)
    except (KeyboardInterrupt, _Stopped):
        bar.close()  # first: the line below would land mid-line after a bar written to a file or pipe
        log.warning("collection stopped: %d new episodes kept in %s; run the same command again to resume",
                    len(new), store.root)
        raise
    finally:
        bar.close()
    tasks = stored_summary(store, pipeline, {s.name: s.group for s in specs}, seeds, var_of)
    return {"new": sorted(new, key=lambda r: (r["task"], r["seed"])), "skipped": skipped, "tasks": tasks}


def plan_suite(suite_dir: Path, tasks: list[str] | str | None, group: str, split: str,
               knobs: dict | None) -> tuple[list[TaskSpec], dict | None, dict[str, dict] | None]:
    """What src/collect.py collects from a simeval suite: (specs, variation, task_variations) for `collect`. Split
    `train` collects every selected task (held-out ones too: the world model's data) under `knobs`; `eval` and
    `heldout` collect the tasks of that split (simeval.sim.tasks.splits), each under its own variation (`knobs` replace
    the eval ones). The suite's splits.yaml is read for every split, so a broken one is an error at once."""
    from simeval.sim.tasks.spec import load_suite, select_specs
    from simeval.sim.tasks.splits import heldout_of, load_heldout, split_tasks

    suite = load_suite(suite_dir)
    specs = select_specs(suite, tasks, group)
    heldout = heldout_of(specs, load_heldout(suite_dir, suite))
    if split == "train":
        return specs, knobs, None
    pairs = split_tasks(specs, split, heldout, eval_override=knobs)
    if not pairs:
        raise UserError(f"variation={split}: none of the selected tasks ({', '.join(s.name for s in specs)}) is in "
                        f"that split; see {suite_dir}/splits.yaml and the tasks' `variations:`")
    return [s for s, _ in pairs], None, {s.name: v for s, v in pairs}


def log_summary(summary: dict, store) -> str | None:
    """Log what a collection did (per task, then the totals) and return the error line for a run in which every
    episode failed (collectors that report failures instead of stopping: GenSim's code), else None."""
    failed = summary.get("failed")
    for task, t in summary["tasks"].items():
        log.info("%-40s %-11s %d/%d oracle successes%s", task, t["group"], t["success"], t["episodes"],
                 f", {len(t['failed'])} failed (seeds {t['failed']})" if t.get("failed") else "")
    log.info("%d new episodes, %d already in %s%s", len(summary["new"]), summary["skipped"], store,
             "" if failed is None else f", {len(failed)} failed")
    if not failed or summary["new"] or summary["skipped"]:
        return None
    first = failed[0]
    return (f"every episode failed; the first, {first['task']} seed {first['seed']}, raised {first['error']}"
            + (f" at {first['where']}" if first["where"] else "") + " (all of them: the log and result.json)")
