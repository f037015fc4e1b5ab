"""Episodes from GenSim's own code: its task classes, `Environment` and oracle, run from the user's GenSim checkout
(`pipeline.root`), one worker process per episode (simeval.pipelines.gensim_own.worker, which says how GenSim is loaded
and what a stored row means), stored in simeval's episode store like any other episode.

Why a process per episode: GenSim drives PyBullet's single global client and leaves state behind in it, prints to
stdout, and its `movej` and settling loops stop on wall-clock timeouts; a process per episode keeps each episode's
physics from the last one's and lets a hung episode be killed at `timeout_s` without losing the others.

Failures are reported, never dropped: an episode whose GenSim code raises or times out is listed in the summary
(task, seed, the error and where GenSim raised it) and logged in one line; the other episodes go on. Resumable:
episodes already in the store are skipped. Workers die with the collector, kill -9 included (worker.py)."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simeval.episodes.episode import Episode
from simeval.episodes.store import EpisodeStore
from simeval.errors import UserError
from simeval.sim.action_spaces import joint_action_space, pick_place_action_space
from simeval.sim.robots.xarm import STATE_NAMES

log = logging.getLogger(__name__)
WORKER = Path(__file__).with_name("worker.py")
CAMERAS = ("top", "front")  # top: GenSim's Oracle camera (the heightmap view: its depth range shows only what is
# within ~0.3 m of the table, so the tool when it comes down, not the arm); front: its first RealSense D415 camera
EXIT_TASK_RAISED, EXIT_UNUSABLE = 3, 4  # as in worker.py (which imports nothing of simeval)
GENSIM_EVAL_VARIATION = {"mode": "test", "unseen_colors": True}  # the eval split: GenSim's test-time task mode
# with its unseen colour set drawn (GensimSettings.unseen_colors): test mode alone changes no scene in most tasks
SCRATCH_PREFIX = ".gensim-work-"  # <store>/.gensim-work-<collector pid>/: the workers' outputs before they are stored


def _remove_stale_scratch(root: Path) -> None:
    """Scratch folders of collectors that no longer run (killed with -9: nothing else skips the cleanup)."""
    for folder in root.glob(f"{SCRATCH_PREFIX}*"):
        pid = folder.name.removeprefix(SCRATCH_PREFIX)
        try:
            os.kill(int(pid), 0)
        except (ValueError, ProcessLookupError):
            shutil.rmtree(folder, ignore_errors=True)
        except PermissionError:  # another user's live collector
            pass


@dataclass(frozen=True)
class GensimSettings:
    """How GenSim's episodes are run: physics rate (GenSim's `hz`), one stored frame every `frame_every` physics
    steps, the interpreter that runs the worker (None: this one), the per-episode time limit of a collection and the
    per-step one of the closed-loop environment (GensimEnv: one pick/place primitive)."""

    root: str
    hz: int = 240
    frame_every: int = 8
    python: str | None = None
    timeout_s: float = 600.0
    step_timeout_s: float = 120.0
    mode: str = "train"  # GenSim's task.mode: train | val | test
    clock: str = "simulated"  # what GenSim's 5-second timeouts read: simulated (physics steps / hz) | wall
    # GenSim's utils.get_colors_names returns TRAIN_COLORS in every mode, so its test mode draws the train colours
    # and EVAL_COLORS (orange, purple, pink, white beside blue, red, green) are never used. True: outside train mode
    # the worker draws EVAL_COLORS, the rule CLIPort's seen/unseen-colour tasks were written for (set in the
    # worker's memory: the checkout's files are not touched). Only tasks that pass their mode to utils.get_colors
    # change; the eval split leaves out the scenes that stay as they were (evaluate.rollout_task)
    unseen_colors: bool = False

    @property
    def control_hz(self) -> float:
        return self.hz / self.frame_every


def check_checkout(root: str | os.PathLike | None) -> Path:
    """`pipeline.root` as a GenSim checkout, or a UserError saying what is missing and how to fix it."""
    if root is None or str(root).strip() == "":
        raise UserError("pipeline.root is not set: give the folder of a GenSim checkout (liruiw/GenSim), e.g. "
                        "pipeline.root=~/GenSim or GENSIM_ROOT=~/GenSim")
    path = Path(str(root)).expanduser()
    need = ["cliport/tasks/__init__.py", "cliport/environments/environment.py", "cliport/environments/assets"]
    missing = [n for n in need if not (path / n).exists()]
    if missing:
        source = " (from GENSIM_ROOT)" if os.environ.get("GENSIM_ROOT") == str(root) else ""
        raise UserError(f"pipeline.root={root}{source} is not a GenSim checkout ({missing[0]} not found): give the "
                        "folder that holds GenSim's cliport/ (git clone https://github.com/liruiw/GenSim)")
    return path.resolve()


def check_settings(s: GensimSettings, control_hz: float) -> None:
    for key, value in (("hz", s.hz), ("frame_every", s.frame_every)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise UserError(f"pipeline.native.{key} must be a whole number >= 1, got {value!r}")
    if abs(s.control_hz - float(control_hz)) > 1e-9:
        raise UserError(f"record.control_hz={control_hz:g} but GenSim's episodes are stored at pipeline.native.hz / "
                        f"frame_every = {s.hz}/{s.frame_every} = {s.control_hz:g} Hz: make them agree")
    if s.mode not in ("train", "val", "test"):
        raise UserError(f"pipeline.native.mode must be train, val or test (GenSim's task.mode), got {s.mode!r}")
    if not isinstance(s.unseen_colors, bool):
        raise UserError(f"pipeline.native.unseen_colors must be true or false, got {s.unseen_colors!r}")
    if s.clock not in ("simulated", "wall"):
        raise UserError(f"pipeline.native.clock must be simulated or wall, got {s.clock!r}")
    for key, value in (("timeout_s", s.timeout_s), ("step_timeout_s", s.step_timeout_s)):
        if isinstance(value, bool) or not (isinstance(value, (int, float)) and value > 0):
            raise UserError(f"pipeline.native.{key} must be a number of seconds > 0, got {value!r}")


class EpisodeFailed(RuntimeError):
    """GenSim's code raised, timed out, or could not be imported for one episode; `unusable`: nothing can run."""

    def __init__(self, task: str, seed: int, error: str, where: str = "", unusable: bool = False) -> None:
        self.task, self.seed, self.error, self.where, self.unusable = task, seed, error, where, unusable
        super().__init__(f"{task} seed {seed}: {error}" + (f" (at {where})" if where else ""))


def worker_request(settings: GensimSettings, task: str, image_size: Sequence[int], cameras: Sequence[str],
                   **more) -> dict:
    """What a worker (recording or serving) is asked to run; `more`: seed and out for a recording."""
    return {"root": settings.root, "task": task, "image_size": list(image_size), "cameras": list(cameras),
            "hz": settings.hz, "frame_every": settings.frame_every, "mode": settings.mode, "clock": settings.clock,
            "unseen_colors": settings.unseen_colors, "parent": os.getpid(), **more}


def worker_environment() -> dict:
    """The worker's environment: no bytecode written into the checkout, fixed hashing, and no PYTHONPATH (the worker
    imports GenSim and numpy only; simeval's path must not shadow them)."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", PYTHONHASHSEED="0")
    env.pop("PYTHONPATH", None)
    return env


def run_worker(task: str, seed: int, settings: GensimSettings, image_size: tuple[int, int],
               cameras: Sequence[str], scratch: Path, live: set | None = None) -> tuple[dict, dict]:
    """Record one episode in a worker process; returns (arrays, meta) or raises EpisodeFailed. `live`: a set the
    running process is kept in, so a collector that is stopped can kill it at once."""
    out = scratch / f"{task}_{seed}"
    req_path = scratch / f"{task}_{seed}.request.json"
    req_path.write_text(json.dumps(worker_request(settings, task, image_size, cameras, seed=int(seed), out=str(out))))
    cmd = [settings.python or sys.executable, str(WORKER), str(req_path)]
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=worker_environment())
    except FileNotFoundError:
        raise EpisodeFailed(task, seed, f"pipeline.native.python={settings.python}: no such interpreter",
                            unusable=True) from None
    if live is not None:
        live.add(proc)
    try:
        _, stderr = proc.communicate(timeout=settings.timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise EpisodeFailed(task, seed, f"timed out after {settings.timeout_s:g} s (pipeline.native.timeout_s)") \
            from None
    finally:
        if live is not None:
            live.discard(proc)
    if proc.returncode != 0:
        last = (stderr.strip().splitlines() or [""])[-1]
        try:
            said = json.loads(last)
        except json.JSONDecodeError:
            said = {"error": f"the worker exited with status {proc.returncode}: {last or 'no message'}"}
        raise EpisodeFailed(task, seed, said.get("error", "?"), said.get("where", ""),
                            unusable=proc.returncode == EXIT_UNUSABLE)
    with np.load(str(out) + ".npz") as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(Path(str(out) + ".json").read_text())
    for p in (Path(str(out) + ".npz"), Path(str(out) + ".json"), req_path):
        p.unlink(missing_ok=True)
    return arrays, meta


def to_episode(arrays: dict, meta: dict, group: str, cameras: Sequence[str], settings: GensimSettings,
               pipeline: str) -> Episode:
    """The worker's output in the store's convention (row 0 the reset observation; the last row's action padding)."""
    actions = arrays["action"]
    if len(actions) == 0:
        raise EpisodeFailed(meta["task"], meta["seed"], "no frame was recorded (the oracle made no move)")
    t = len(actions)
    progress = arrays["progress"].astype(np.float32)
    hz = settings.control_hz
    description = meta["docstring"] if meta["docstring"] is not None else "None"
    extra = {"gensim": {k: meta[k] for k in ("lang_goal", "total_reward", "done", "primitives", "max_steps",
                                                "physics_steps", "hz", "frame_every", "mode", "task_class",
                                                "stood_in", "clock", "movej_timeouts")}
                       | ({"unseen_colors": True} if meta.get("unseen_colors") else {}),  # absent: GenSim's rule
             "checkout": Path(settings.root).name}
    return Episode(
        pipeline=pipeline, task=meta["task"], description=description, group=group, seed=int(meta["seed"]),
        rgb={c: arrays[f"rgb/{c}"] for c in cameras}, state=arrays["state"],
        action=np.concatenate([actions, actions[-1:]]), reward=np.r_[np.diff(progress), 0.0].astype(np.float32),
        progress=progress, is_first=np.arange(t + 1) == 0, is_terminal=np.arange(t + 1) == t,
        success=bool(meta["success"]), high_level_action=arrays["high_level_action"],
        high_level_step=arrays["high_level_step"], high_level_space=pick_place_action_space(hz), control_hz=hz,
        source="gensim", action_space=joint_action_space(hz), state_names=list(STATE_NAMES),
        robot_mask={c: arrays[f"robot_mask/{c}"].astype(bool) for c in cameras},
        object_poses=arrays["object_poses"],
        language=[meta["lang_goal"]] * (t + 1), extra=extra)


def collect_gensim(tasks: dict[str, str], seeds: Sequence[int], store: EpisodeStore, settings: GensimSettings,
                   image_size: tuple[int, int], cameras: Sequence[str] = CAMERAS, *, pipeline: str = "gensim_own",
                   workers: int = 1, progress: bool = True) -> dict:
    """Record `seeds` of each task ({name: group}) with GenSim's own code into `store`. Returns {"new": [...],
    "skipped": n, "failed": [{task, seed, error, where}], "tasks": {task: {group, episodes, success, rate,
    failed}}}. Raises UserError when GenSim cannot be imported at all (the first worker says why)."""
    from tqdm import tqdm

    from simeval.collect import missing_episodes, stored_summary
    from simeval.sim.action_spaces import JOINT_KIND
    from simeval.sim.rollout import RecordSettings

    unknown = [c for c in cameras if c not in CAMERAS]
    if unknown:
        raise UserError(f"record.cameras: GenSim's episodes have cameras {list(CAMERAS)}, not {unknown}")
    recorded_as = RecordSettings(cameras=tuple(cameras), image_size=image_size, control_hz=settings.control_hz)
    todo = missing_episodes(store, pipeline, dict.fromkeys(tasks), seeds, recorded_as, dict.fromkeys(tasks, JOINT_KIND))
    skipped = len(tasks) * len(seeds) - len(todo)
    plural = "" if workers == 1 else "s"
    bar = tqdm(total=len(todo), desc=f"GenSim episodes ({workers} worker{plural})", unit="episode", disable=not progress)
    _remove_stale_scratch(store.root)
    scratch = store.root / f"{SCRATCH_PREFIX}{os.getpid()}"
    scratch.mkdir(exist_ok=True)
    live: set = set()  # running worker processes
    try:

        def one(task: str, seed: int) -> dict:
            t0 = time.perf_counter()
            arrays, meta = run_worker(task, seed, settings, image_size, cameras, scratch, live)
            ep = to_episode(arrays, meta, tasks[task], cameras, settings, pipeline)
            path = store.write(ep)
            return {"task": task, "seed": seed, "success": ep.success, "steps": ep.n_steps,
                    "seconds": time.perf_counter() - t0, "gensim_seconds": meta["seconds"],
                    "bytes": os.path.getsize(path)}

        new, failed = _record_in_workers(one, todo, workers, live, bar, settings)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    out = stored_summary(store, pipeline, tasks, seeds, failed=failed)
    return {"new": sorted(new, key=lambda r: (r["task"], r["seed"])), "skipped": skipped,
            "failed": sorted(failed, key=lambda r: (r["task"], r["seed"])), "tasks": out}


def _record_in_workers(one, todo: list, workers: int, live: set, bar, settings: GensimSettings) -> tuple[list, list]:
    """`one(task, seed)` for each of `todo` on `workers` threads: (what each returned, the failures reported).
    A GenSim that cannot be used at all stops every worker with a UserError; so does Ctrl-C (re-raised)."""
    new, failed = [], []
    with ThreadPoolExecutor(max(1, workers)) as pool:  # threads only wait: each episode is its own process
        futures = {pool.submit(one, t, s): (t, s) for t, s in todo}
        try:
            for f in as_completed(futures):
                try:
                    new.append(f.result())
                except EpisodeFailed as e:
                    if e.unusable:
                        raise UserError(f"GenSim at {settings.root} cannot be used: {e.error}"
                                        + (f" (at {e.where})" if e.where else "")
                                        + "; set up its environment with `make gensim-env` (README, GenSim's "
                                          "own code)") from None
                    log.warning("GenSim %s seed %d failed, reported: %s%s", e.task, e.seed, e.error,
                                f" (at {e.where})" if e.where else "")
                    failed.append({"task": e.task, "seed": e.seed, "error": e.error, "where": e.where})
                bar.update(1)
        except BaseException:  # Ctrl-C, or GenSim unusable: stop the workers now, keep what is stored
            for f in futures:
                f.cancel()
            for proc in list(live):
                proc.kill()
            raise
        finally:
            bar.close()
    return new, failed


def plan_tasks(root: Path, tasks: list[str] | str | None, group: str) -> dict[str, str]:
    """{task: group} from GenSim's registry (a static parse: simeval.pipelines.gensim.tasks) by the authors' substring rule:
    the tasks of `group` (or of every group for `all`), or the named `tasks` (any registered task; its group is
    the first the rule gives, `ungrouped` for none)."""
    from simeval.pipelines.gensim.tasks import gensim_groups, load_gensim_checkout, registered_names
    from simeval.pipelines.task_records import TaskSourceError

    try:
        registry = load_gensim_checkout(root)
    except TaskSourceError as e:
        raise UserError(str(e)) from None
    if tasks:
        names = [tasks] if isinstance(tasks, str) else list(tasks)
        known = set(registered_names(root))
        unknown = [n for n in names if n not in known]
        if unknown:
            import difflib

            close = list(dict.fromkeys(c for n in unknown for c in difflib.get_close_matches(n, known, cutoff=0.6)))
            mean = f"did you mean {', '.join(close)}? " if close else ""
            raise UserError(f"tasks: {unknown} not in GenSim's registry at {root} ({mean}{len(known)} tasks in "
                            f"cliport/tasks/__init__.py `names` and cliport/generated_tasks)")
        if group != "all":
            raise UserError("give tasks= or task_group=, not both (leave task_group=all with tasks=)")
        return {n: (gensim_groups(n) or ["ungrouped"])[0] for n in names}
    groups = sorted({t.group for t in registry})
    if group != "all" and group not in groups:
        raise UserError(f"task_group={group}: GenSim's groups (the authors' substring rule) are {', '.join(groups)}, "
                        "or all")
    picked: dict[str, str] = {}
    for t in registry:
        if group in ("all", t.group):
            picked.setdefault(t.name, t.group)
    return picked


def collect_from_checkout(root, native: dict, tasks, group: str, seeds: Sequence[int], store, record: dict, *,
                          pipeline: str = "gensim_own", workers: int = 0, progress: bool = True) -> dict:
    """src/collect.py for a pipeline with `native:` settings: checks the checkout and settings, plans the tasks,
    collects (collect_gensim). `record`: the collector's record settings (cameras, image_size, control_hz)."""
    from simeval.collect import worker_count
    from simeval.sim.rollout import RecordSettings

    path = check_checkout(root)
    settings = GensimSettings(root=str(path), **native)
    recording = RecordSettings(**record)  # the suites' checks of record.* (cameras, sizes, rate), one place
    check_settings(settings, recording.control_hz)
    workers = worker_count(workers)
    return collect_gensim(plan_tasks(path, tasks, group), seeds, EpisodeStore(store), settings,
                          recording.image_size, recording.cameras, pipeline=pipeline,
                          workers=workers, progress=progress)

