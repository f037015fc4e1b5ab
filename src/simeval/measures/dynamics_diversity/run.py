"""Dynamics-based trajectory diversity (paper Sec. 3.4, Table 4): train a world model on the first k episodes of
each task of a group and evaluate it on the first 40 (and, when they exist, on held-out episodes 41-50).

`fit_and_evaluate` takes a source of episodes (simeval.episodes.dataset.StoreSource or ArraySource) and plain
configs, and returns the numbers result.json records; src/diversity.py is its command line. A falling error from
k = 10 to 40 says the group's dynamics need more data to learn, i.e. are diverse (the paper's reading).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import shutil
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from simeval.episodes.dataset import (
    WindowDataset,
    WindowSpec,
    build_index,
    episode_ranks,
    epoch_offset,
    rank_mask,
    require_ranks,
    window_starts,
)
from simeval.episodes.digest import arrays_digest, source_digest
from simeval.errors import EpisodesUnfit, UserError
from simeval.media import write_video
from simeval.results import atomic_write_text
from simeval.runtime.device import resolve_device
from simeval.measures.dynamics_diversity.gate import GateConfig, pixel_gate
from simeval.measures.dynamics_diversity.state_reading import VERSION as STATE_VERSION
from simeval.measures.dynamics_diversity.state_reading import (StateModelConfig, read_states, robot_dims,
                                                              state_reading)
from simeval.models.world_model_training import TrainConfig, evaluate, load_checkpoint, train
from simeval.models.world_model import VERSION, WorldModel, WorldModelConfig, open_loop_video

log = logging.getLogger(__name__)

VIDEO_FPS = 5  # a window's frames are control steps: the paper's 40-step window plays in 8 s


def data_fingerprint(infos) -> str:
    """sha1 of the (task, seed, rows) list: which episodes a run read (its identity's `episodes_sha`). Not their
    content: a checkpoint's key adds simeval.episodes.digest.source_digest for that."""
    text = json.dumps(sorted((i.task, int(i.seed), int(i.n_rows)) for i in infos))
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def check_eval_context(context: int | None, window: WindowSpec) -> None:
    if context is not None and not 1 <= int(context) < window.length:
        raise UserError(f"eval.context={context}: expected 1 <= context < window length ({window.length})")


def check_every_task_has_windows(infos, train_mask: np.ndarray, window: WindowSpec, seed: int = 0,
                                 epochs: int = 1) -> None:
    """A UserError naming the tasks none of whose training episodes holds a window in any epoch (at the offsets
    the epochs draw from `seed` with random_offset, else at the window's offset; with its pad_start and pad_end):
    the model would never train on them, yet their episodes are evaluated (padded), so their error would be that of
    a model that never saw the task. Our RoboGen-style episodes (22-77 rows) meet this with the `paper` preset's
    windows of 40; the authors' DreamerV3 fork instead ran a window on into the next episode, which ours never do.
    The length suggested is the longest with which every task has a window at those offsets."""
    offsets = sorted({epoch_offset(window, seed, e) for e in range(max(1, epochs))})
    has_window = lambda n: any(len(window_starts(n, window, off)) for off in offsets)  # noqa: E731
    longest: dict[str, int] = {}
    trained: set[str] = set()
    for info, used in zip(infos, train_mask):
        if used:
            longest[info.task] = max(longest.get(info.task, 0), int(info.n_rows))
            if has_window(int(info.n_rows)):
                trained.add(info.task)
    short = {t: n for t, n in sorted(longest.items()) if t not in trained}
    if short:
        fits = max(1, min(short.values()) - (offsets[0] - window.pad_start))  # [s, s + L) needs s + L <= rows
        listed = ", ".join(f"{t} ({n})" for t, n in short.items())
        start = offsets[0] - window.pad_start
        where = f"; the windows start {start} row{'s' * (start != 1)} in at the earliest" if start > 0 else ""
        raise EpisodesUnfit(f"world_model.window.length={window.length}: {len(short)} of {len(longest)} tasks have "
                            "no training episode that holds a window, so the model would never see them (longest "
                            f"rows: {listed}{where}); use world_model.window.length={fits} or "
                            "world_model.window.pad_end=true" + (
                                f", or more epochs: these {max(1, epochs)} draw {len(offsets)} window offset(s) "
                                "(world_model.train.epochs; under protocol=heldout a larger protocol.steps)"
                                if window.random_offset else ""))


def check_frames_not_upsampled(source, image_size: int) -> None:
    """A UserError when the episodes' frames are smaller than the model's: the dataset would upsample them, and an
    image error measured on blurred frames is not the error at `image_size` (e.g. the `paper` preset's 128x128 on a
    store recorded at the default 64x64). Larger frames are downsampled, as the `cpu` preset does with a 128x128
    store."""
    sizes = {source.frame_size(e) for e in range(len(source.infos))}
    small = sorted(s for s in sizes if min(s) < image_size)
    if small:
        h, w = small[0]
        raise EpisodesUnfit(f"the episodes' frames are {h}x{w}, smaller than the model's world_model.model."
                            f"image_size={image_size}: they would be upsampled; record the episodes at that size in a "
                            f"store of their own (src/collect.py ... 'record.image_size=[{image_size},{image_size}]' "
                            f"store=DIR, then store=DIR here), or set world_model.model.image_size to at most "
                            f"{min(h, w)} (minres times a power of two)")


@dataclass(frozen=True)
class Training:
    """What a world model learns from and how (all of it in the checkpoint's key): its config, its optimiser's, the
    training windows, and the heldout protocol's budget: `steps` gradient steps for every episode count, Adam's
    learning rate `lr` (None: train's), `exclude_robot_from_loss` (robot pixels, grown by Evaluation.mask_margin,
    carry no loss)."""

    model: WorldModelConfig
    train: TrainConfig
    window: WindowSpec
    steps: int | None = None
    lr: float | None = None
    exclude_robot_from_loss: bool = False


@dataclass(frozen=True)
class Evaluation:
    """What a run is scored on and how: the protocol ("paper" or "heldout", PROTOCOLS), the evaluated ranks
    `episodes` [lo, hi) and the paper protocol's `heldout_episodes`, the evaluation's seed, observed context, batch
    size and open-loop `horizon`, the robot masks' `mask_margin` (pixels), the validity `gate` and the
    `state_model` of the heldout protocol (None: their defaults / no state reading), `pixels` (heldout: False reads
    the states only, no world model trained), and `videos` open-loop videos written to `video_dir`."""

    protocol: str = "paper"
    episodes: tuple[int, int] = (0, 40)
    heldout_episodes: tuple[int, int] | None = (40, 50)
    seed: int = 0
    context: int | None = None
    batch_size: int = 16
    horizon: int | None = None
    mask_margin: int = 0
    gate: GateConfig | None = None
    state_model: StateModelConfig | None = None
    pixels: bool = True
    videos: int = 0
    video_dir: str | Path | None = None


@dataclass(frozen=True)
class Execution:
    """Where and how a run executes, none of it in the checkpoint's key: `checkpoint_dir` (None: no checkpoint),
    `device` (auto, cpu, cuda, cuda:N), `compile` and `capture` (a GPU's), `progress` bars, `log_metrics(metrics,
    step)`, `evaluate_only` (heldout: a UserError instead of training when the checkpoint is not there) and
    `how_to_get_more(n)`, what a too-few-episodes error tells the user to run."""

    checkpoint_dir: str | Path | None = None
    device: str | torch.device | None = "auto"
    compile: bool = False
    capture: bool = False
    progress: bool = True
    log_metrics: Callable[[dict, int], None] | None = None
    evaluate_only: bool = False
    how_to_get_more: Callable[[int], str] | None = None


def fit_and_evaluate(source, episodes_per_task: int, training: Training, evaluation: Evaluation = Evaluation(),
                     execution: Execution = Execution()) -> dict:
    """Train on ranks [0, episodes_per_task) of every task (`training`), evaluate on ranks `evaluation.episodes`
    (and, under the paper protocol, `evaluation.heldout_episodes` when every task has them). Returns {eval,
    heldout, train, model, tasks, checkpoint, videos} (paper) or {protocol, prediction, gate, state, train, model,
    tasks, checkpoint, videos} (heldout).

    With `execution.checkpoint_dir`, the model is checkpointed there under a name keyed by its config and training
    data, so the same command run again resumes a killed run (or, when it finished, only evaluates); the device,
    `compile` (WorldModel.compile_steps) and `capture` (one CUDA graph per step, simeval.runtime.captured) are not
    part of the key, so a run resumes on another device; `train.segments` records how each part of the training
    ran. With `evaluation.videos` > 0 and a `video_dir`, the open-loop prediction videos of the first tasks are
    written there as `open_loop_<task>.mp4`.

    `evaluation.protocol`: "paper" (the paper's Table 4 quantity: the posterior reconstruction averaged over the
    evaluated episodes, which include the training episodes; the budget is `training.train`'s epochs, so it grows
    with the episodes) or "heldout" (what simeval's own readings rest on, see PROTOCOLS): the evaluated episodes
    must lie past every training episode, every episode count trains for the same `training.steps`, and
    `values["prediction"]` holds one-step and `horizon`-step open-loop prediction errors after `context` observed
    frames, with the last-frame and per-task-mean-image baselines, skill scores, object-focused errors (robot
    pixels, grown by `mask_margin`, excluded where the episodes carry robot masks; with
    `training.exclude_robot_from_loss` they carry no training loss either) and per-episode sums for intervals
    (simeval.measures.dynamics_diversity.prediction); `values["gate"]` says whether the model beats both baselines
    on the held-out frames, per task and for the group (where it does not, its numbers are no reading);
    `values["state"]` is the state-space reading on the same episodes (simeval.measures.dynamics_diversity.
    state_reading), gated on its own. With `evaluation.pixels` False (heldout) no world model is trained nor read:
    `values["prediction"]`, `["gate"]`, `["train"]` and `["model"]` are None and the state reading is the run's.
    `values["readings"]` (heldout) says first what each reading's numbers are (see `readings`)."""
    device = resolve_device(execution.device)  # a bad value fails here, before any data is read
    execution = replace(execution, device=device)
    if evaluation.protocol not in PROTOCOLS:
        raise UserError(f"protocol={evaluation.protocol!r}: expected one of {', '.join(PROTOCOLS)}")
    if evaluation.protocol == "heldout":
        values = _fit_and_evaluate_heldout(source, episodes_per_task, training, evaluation, execution)
        return {"readings": readings(values), **values}
    model_cfg, train_cfg, window = training.model, training.train, training.window
    eval_episodes, heldout_episodes, eval_seed = evaluation.episodes, evaluation.heldout_episodes, evaluation.seed
    videos, video_dir = evaluation.videos, evaluation.video_dir
    progress, compile = execution.progress, execution.compile
    setup = _prepare(source, episodes_per_task, training, execution, eval_episodes=eval_episodes,
                     eval_context=evaluation.context)
    tasks, ranks, train_ds, stats = setup.tasks, setup.ranks, setup.train_ds, setup.stats
    model, meta, checkpoint = setup.model, setup.meta, setup.checkpoint
    eval_spec = WindowSpec(length=window.length, stride=window.length, pad_end=True)

    def run_eval(lo: int, hi: int) -> dict:
        ds = WindowDataset(source, eval_spec, rank_mask(ranks, lo, hi), stats=stats, image_size=model_cfg.image_size)
        if ds.action_space.get("kind") != train_ds.action_space.get("kind"):
            raise EpisodesUnfit("evaluation episodes have another action space than the training ones")
        out = evaluate(model, ds, seed=eval_seed, batch_size=evaluation.batch_size, context=evaluation.context,
                       progress=progress)
        out["episodes"] = [lo + 1, hi]
        return out, ds

    counts = {t: int(np.sum(np.asarray(tasks) == t)) for t in set(tasks)}
    with WorldModel.compile_failures_named(compile):  # training, and the evaluations' new shapes compiled too
        summary = _train(model, train_ds, train_cfg, checkpoint, meta, execution)
        main_eval, eval_ds = run_eval(*eval_episodes)
        values = {"eval": main_eval, "heldout": None, "videos": {}}
        clips = (prediction_videos(model, eval_ds, main_eval["context"], seed=eval_seed, n_tasks=videos)
                 if videos > 0 and video_dir is not None else {})
        if heldout_episodes is not None and min(counts.values()) >= heldout_episodes[1]:
            values["heldout"] = run_eval(*heldout_episodes)[0]
        elif heldout_episodes is not None:
            log.info("no held-out evaluation: needs %d episodes per task, the fewest is %d", heldout_episodes[1],
                     min(counts.values()))
    values["videos"] = {task: str(write_video(frames, Path(video_dir) / f"open_loop_{task}.mp4", fps=VIDEO_FPS))
                        for task, frames in clips.items()}
    values["train"] = setup.train_summary(summary, device, compile, execution.capture)
    values["model"] = setup.model_summary()
    values["tasks"] = sorted(counts)
    values["checkpoint"] = str(checkpoint) if checkpoint is not None else None
    return values


def _train(model, dataset, train_cfg: TrainConfig, checkpoint, meta: dict, execution: Execution) -> dict:
    return train(model, dataset, train_cfg, checkpoint=checkpoint, meta=meta, log_metrics=execution.log_metrics,
                 progress=execution.progress, device=execution.device, compile=execution.compile,
                 capture=execution.capture)


PROTOCOLS = {
    "paper": "the paper's Table 4: posterior reconstruction on episodes 1-40 (the training episodes among them), "
             "10 epochs (the budget grows with the episodes)",
    "heldout": "simeval's readings: prediction of held-out episodes (41-50) from actions, the same gradient steps "
               "for every episode count, beside last-frame and mean-image baselines",
}
# conf/protocol/heldout.yaml's keys that conf/protocol/paper.yaml lacks: read only under protocol=heldout
HELDOUT_ONLY = ("gate", "state_model", "pixels", "model")
# heldout.yaml's keys that paper.yaml lacks too, but that debug=tiny sets (steps, horizon) whichever protocol runs:
# under protocol=paper they are refused where given on the command line (simeval.cli's check, before Hydra), and
# otherwise left unread
HELDOUT_BUDGET = ("steps", "lr", "horizon", "mask_margin", "exclude_robot_from_loss")


def refuse_heldout_settings_given(overrides: list[str], protocol: str) -> None:
    """A UserError for a command-line override of a HELDOUT_BUDGET key under another protocol, which would run
    without reading it. simeval.cli refuses these before Hydra, except with HYDRA_FULL_ERROR=1 or another config
    folder (--config-dir), where it does not check: the run itself does, from Hydra's record of its overrides."""
    if protocol == "heldout":
        return
    for given in overrides:
        key = given.lstrip("+").split("=", 1)[0]
        section, _, name = key.partition(".")
        if section == "protocol" and name.split(".")[0] in HELDOUT_BUDGET and not given.startswith("~"):
            raise UserError(f"{given}: protocol={protocol} has no {name.split('.')[0]} (a setting of "
                            f"protocol=heldout); drop it, or run it with protocol=heldout")


def budget_epochs(n_rows, train_mask: np.ndarray, window: WindowSpec, batch_size: int, steps: int) -> int:
    """Epochs enough for `steps` gradient steps however the epochs' random offsets cut the windows: steps divided
    by the fewest batches any offset gives, rounded up (training stops at `steps` through max_steps)."""
    fewest = min(len(build_index(n_rows, window, train_mask, off)) for off in range(window.stride))
    if fewest == 0:
        return 1  # no window at some offset: the window check names the tasks
    return int(math.ceil(steps / math.ceil(fewest / batch_size)))


def _yaml(value) -> str:
    """A config value as the user wrote it: null for None, else its repr."""
    return "null" if value is None else repr(value)


def _whole(value, low: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= low


def check_heldout_settings(steps, horizon, lr, mask_margin, context: int, exclude_robot_from_loss=False) -> None:
    """One UserError naming the first protocol.* (or eval.context) value the heldout protocol cannot use."""
    if not _whole(steps, 1):
        raise UserError(f"protocol.steps={steps!r}: the heldout protocol trains every episode count for the same "
                        "whole number of gradient steps >= 1")
    if not _whole(horizon, 1):
        raise UserError(f"protocol.horizon={horizon!r}: expected a whole number >= 1 (frames imagined after "
                        f"eval.context={context} observed ones)")
    if context < 1:
        raise UserError(f"eval.context={context}: expected a whole number >= 1")
    if not _whole(mask_margin, 0):
        raise UserError(f"protocol.mask_margin={_yaml(mask_margin)}: expected a whole number of pixels >= 0")
    if not isinstance(exclude_robot_from_loss, bool):
        raise UserError(f"protocol.exclude_robot_from_loss={_yaml(exclude_robot_from_loss)}: expected true or false")
    if lr is not None and (isinstance(lr, bool) or not isinstance(lr, (int, float)) or not lr > 0):
        raise UserError(f"protocol.lr={lr!r}: expected a number > 0, or null for the preset's world_model.train.lr")


def _refuse_training_on_evaluated(source, k: int, lo: int, hi: int, how_to_get_more) -> None:
    """A UserError when training on the first k episodes would reach the evaluated ranks lo..hi-1 (0-based), with
    the eval_episodes (or the collection) that would fix it."""
    if lo >= k:
        return
    have = min(Counter(i.task for i in source.infos).values(), default=0)  # episodes per task in the store
    fix = (f"e.g. eval_episodes=[{k + 1},{min(have, k + 10)}]" if have > k else
           f"with more episodes (the store holds {have} per task, at the fewest): "
           + (how_to_get_more(k + 10) if how_to_get_more is not None else f"collect episodes={k + 10}")
           + f", then eval_episodes=[{k + 1},{k + 10}]")
    raise UserError(f"protocol=heldout: episodes={k} would train on evaluated episodes (eval_episodes="
                    f"[{lo + 1},{hi}]); evaluate past the largest episode count of the sweep, {fix}")


def _refuse_windows_longer_than_episodes(source, evaluated: np.ndarray, context: int, horizon: int) -> None:
    longest = max(i.n_rows for i, m in zip(source.infos, evaluated) if m)
    if context + horizon > longest:
        raise UserError(f"protocol.horizon={horizon} with eval.context={context}: open-loop windows of "
                        f"{context + horizon} rows, but the evaluated episodes have at most {longest} rows; use "
                        f"protocol.horizon={max(1, longest - context)} or less")


def _fit_and_evaluate_heldout(source, episodes_per_task: int, training: Training, evaluation: Evaluation,
                              execution: Execution) -> dict:
    """The `heldout` protocol of fit_and_evaluate (see its docstring). Long because it is the protocol read in
    order, each step one call: refusals, the equal budget, training, the prediction reading, the state reading."""
    from simeval.measures.dynamics_diversity.prediction import evaluate_prediction, task_mean_images

    model_cfg, train_cfg, window = training.model, training.train, training.window
    steps, lr, exclude_robot_from_loss = training.steps, training.lr, training.exclude_robot_from_loss
    horizon, mask_margin, how_to_get_more = evaluation.horizon, evaluation.mask_margin, execution.how_to_get_more
    videos, video_dir, compile = evaluation.videos, evaluation.video_dir, execution.compile
    k = int(episodes_per_task)
    lo, hi = evaluation.episodes
    _refuse_training_on_evaluated(source, k, lo, hi, how_to_get_more)
    if not evaluation.pixels:
        return _states_only(source, k, evaluation, how_to_get_more, execution.checkpoint_dir)
    context = 5 if evaluation.context is None else int(evaluation.context)
    check_heldout_settings(steps, horizon, lr, mask_margin, context, exclude_robot_from_loss)
    # the budget: `steps` for every episode count (an epoch count that cannot run short; max_steps stops it)
    ranks = episode_ranks([i.task for i in source.infos], [i.seed for i in source.infos])
    epochs = budget_epochs([i.n_rows for i in source.infos], rank_mask(ranks, 0, k), window, train_cfg.batch_size,
                           steps)
    train_cfg = replace(train_cfg, epochs=epochs, max_steps=steps, lr=train_cfg.lr if lr is None else float(lr))

    def more(n: int) -> str:  # besides collecting: evaluate what the store has, or the paper's protocol
        how = how_to_get_more(n) if how_to_get_more is not None else f"collect more: src/collect.py episodes={n}"
        return (f"{how}; or evaluate episodes the store has past the training ones, eval_episodes=[{k + 1},LAST], "
                "or use protocol=paper")

    setup = _prepare(source, k, replace(training, train=train_cfg), replace(execution, how_to_get_more=more),
                     eval_episodes=evaluation.episodes, eval_context=None, protocol="heldout",
                     loss_robot_margin=mask_margin if exclude_robot_from_loss else None)
    if execution.evaluate_only and (setup.checkpoint is None or not Path(setup.checkpoint).exists()):
        raise UserError(f"no checkpoint to evaluate from ({setup.checkpoint or 'checkpoint_dir is null'}): this run "
                        "would have to be trained again")
    evaluated = rank_mask(setup.ranks, lo, hi)
    _refuse_windows_longer_than_episodes(source, evaluated, context, horizon)

    def held_out(length: int) -> WindowDataset:
        return WindowDataset(source, WindowSpec(length=length, stride=length, pad_end=True), evaluated,
                             stats=setup.stats, image_size=model_cfg.image_size, robot_masks=True,
                             mask_margin=mask_margin)

    step_ds, eval_ds = held_out(window.length), held_out(context + horizon)  # one step; open loop
    if eval_ds.action_space.get("kind") != setup.train_ds.action_space.get("kind"):
        raise EpisodesUnfit("evaluation episodes have another action space than the training ones")
    if np.any(setup.train_mask & eval_ds.episodes):  # the ranks above make this impossible; a guard on the plumbing
        raise RuntimeError("an evaluated episode is among the training episodes")
    means = task_mean_images(source, setup.train_mask, model_cfg.image_size)
    with WorldModel.compile_failures_named(compile):
        summary = _train(setup.model, setup.train_ds, train_cfg, setup.checkpoint, setup.meta, execution)
        started = time.perf_counter()
        prediction = evaluate_prediction(setup.model, step_ds, eval_ds, means, context, seed=evaluation.seed,
                                         batch_size=evaluation.batch_size, progress=execution.progress)
        prediction["seconds"] = time.perf_counter() - started  # what a sweep spends beside training (benchmarks)
        clips = (prediction_videos(setup.model, eval_ds, context, seed=evaluation.seed, n_tasks=videos)
                 if videos > 0 and video_dir is not None else {})
    prediction["episodes"] = [lo + 1, hi]
    values = {"protocol": {"name": "heldout", "steps": steps, "lr": train_cfg.lr, "mask_margin": mask_margin,
                           "exclude_robot_from_loss": exclude_robot_from_loss,
                           "robot_excluded_from_loss": setup.train_ds.robot_masks, "trained_on": [1, k],
                           "evaluated_on": [lo + 1, hi], "context": context, "horizon": horizon},
              "prediction": prediction,
              "gate": pixel_gate([prediction["per_episode"]], evaluation.gate or GateConfig()),
              "state": None if evaluation.state_model is None else
              _state_reading(source, setup.train_mask, evaluated, evaluation.state_model, evaluation.gate,
                             execution.checkpoint_dir),
              "videos": {task: str(write_video(frames, Path(video_dir) / f"open_loop_{task}.mp4", fps=VIDEO_FPS))
                         for task, frames in clips.items()},
              "train": setup.train_summary(summary, execution.device, compile, execution.capture),
              "model": setup.model_summary(),
              "tasks": sorted(set(setup.tasks)),
              "checkpoint": str(setup.checkpoint) if setup.checkpoint is not None else None}
    return values


def _states_only(source, k: int, evaluation: Evaluation, how_to_get_more, cache_dir: str | Path | None) -> dict:
    """The heldout protocol with `evaluation.pixels` False: the same training and evaluated episodes as a run with
    pixels (the ranks), the state reading alone; no frame is read, so episodes without frames serve."""
    if evaluation.state_model is None:
        raise UserError("protocol.pixels=false with protocol.state_model=null: the run would read nothing; give "
                        "protocol.state_model its settings (conf/protocol/heldout.yaml) or protocol.pixels=true")
    lo, hi = evaluation.episodes
    tasks = [i.task for i in source.infos]
    ranks = episode_ranks(tasks, [i.seed for i in source.infos])
    require_ranks(tasks, ranks, max(k, hi), f"training on {k} and evaluating on episodes {lo + 1}-{hi}",
                  how_to_get_more)
    train_mask, evaluated = rank_mask(ranks, 0, k), rank_mask(ranks, lo, hi)
    return {"protocol": {"name": "heldout", "pixels": False, "trained_on": [1, k], "evaluated_on": [lo + 1, hi]},
            "prediction": None, "gate": None,
            "state": _state_reading(source, train_mask, evaluated, evaluation.state_model, evaluation.gate,
                                    cache_dir),
            "videos": {}, "train": None, "model": None, "tasks": sorted(set(tasks)), "checkpoint": None}


def _state_reading(source, train_mask: np.ndarray, evaluated: np.ndarray, cfg: StateModelConfig,
                   gate: GateConfig | None, cache_dir: str | Path | None = None) -> dict:
    """The state reading of a run (state_reading); with `cache_dir`, kept there as `state_reading-<key>.json`, the
    key its inputs by value (the states, actions and presence masks read, which episodes train and which are
    evaluated, the settings, the reading's version), so a sweep run again after a kill skips the counts it read and
    the seeds of a sweep with pixels, whose state reading is one and the same, train it once; its models' training
    is saved beside it in `state_reading-<key>/` as it goes (removed once the reading is kept), so a run killed
    mid-reading resumes at the seed and step it reached."""
    train_idx, eval_idx = np.flatnonzero(train_mask).tolist(), np.flatnonzero(evaluated).tolist()
    states = read_states(source, train_idx + eval_idx)
    tasks, dims = [i.task for i in source.infos], robot_dims(source, train_idx + eval_idx)
    gate = gate or GateConfig()
    cache = training = None
    if cache_dir is not None:
        key = _state_key(states, tasks, train_idx, eval_idx, cfg, gate, dims)
        cache = Path(cache_dir) / f"state_reading-{key}.json"
        training = Path(cache_dir) / f"state_reading-{key}"
        if cache.exists():
            try:
                out = json.loads(cache.read_text())
                if not isinstance(out, dict) or not {"line", "gate", "summary"} <= set(out):
                    raise ValueError("not a state reading")
            except (OSError, ValueError) as e:  # a file cut short by a full disk: read again, and rewrite it
                log.warning("state reading: %s unreadable (%s); reading the states again", cache, e)
            else:
                log.info("state reading: read before, from %s", cache)
                return {**out, "cache": str(cache)}
    started = time.perf_counter()
    # it shows no progress of its own (seconds to two minutes at cpu): a log that stopped here is not a hung run
    log.info("state reading: training %d state models (up to %d steps each) on %d episodes", len(cfg.seeds),
             cfg.max_steps, len(train_idx))
    try:
        refuse_poses_recorded_apart(source, states, dims)
        out = state_reading(states, tasks, train_idx, eval_idx, cfg, gate, robot_dims=dims, checkpoints=training)
    except UserError as e:  # its settings were checked before any data was read: this is the data's, a reading
        why = f"no reading: {e}"  # that cannot be made, not a failed run (the pixel reading still stands)
        return {"dims": None, "gate": {"passes": False, "verdict": why}, "summary": {}, "line": why,
                "seconds": time.perf_counter() - started}
    out["seconds"] = time.perf_counter() - started
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(cache, json.dumps(out, default=lambda v: v.tolist() if hasattr(v, "tolist") else str(v)))
        shutil.rmtree(training, ignore_errors=True)
    return out


def refuse_poses_recorded_apart(source, states: dict, robot_dims: int) -> None:
    """An EpisodesUnfit where a task of simeval's suites has episodes recorded with their moving links' poses
    (more pose rows than bodies) and episodes recorded without them (a store collected before 2026-12-06 and topped
    up since): padded into one layout, the earlier episodes' drawers and lids would never move, and the reading
    would be neither's (a newcomer's trial: 7 of 14 episodes per task recorded before read 6x the error; 10 training
    episodes before and 4 held out after read no model beating the last state). `states` from read_states: each
    episode's pose rows are its values past the robot's `robot_dims`, 7 per row (present rows, where padded)."""
    by_task: dict = {}
    for e, entry in states.items():
        info = source.infos[e]
        bodies = info.extra.get("bodies")
        rows = (int(np.sum(entry[2][robot_dims::7])) if len(entry) > 2  # a row present: its x (a particle's too)
                else (int(entry[0].shape[1]) - robot_dims) // 7)
        if bodies is None or rows <= 0:
            continue
        with_links = by_task.setdefault(info.task, {True: [], False: []})
        with_links[rows > int(bodies)].append(info.path or f"seed {info.seed}")
    mixed = [(task, split) for task, split in sorted(by_task.items()) if split[True] and split[False]]
    if mixed:
        (task, split), others = mixed[0], mixed[1:]
        also = "" if not others else ("; so were " + ", ".join(
            f"{len(s[False])} of task {t}'s {len(s[False]) + len(s[True])}" for t, s in others))
        raise EpisodesUnfit(
            f"task {task}: {len(split[False])} of its episodes were recorded without their moving links' poses "
            f"(collected before 2026-12-06, e.g. {split[False][0]}) and {len(split[True])} with them{also}; "
            "collect the group again into an empty store (src/collect.py ... store=<new folder>)")


def _state_key(states: dict, tasks: list[str], train_idx: list[int], eval_idx: list[int], cfg: StateModelConfig,
               gate: GateConfig, robot_dims: int | None) -> str:
    """16 hex digits of what a state reading reads, by value (simeval.episodes.digest for the arrays)."""
    data = arrays_digest({f"{i}": a for i, a in enumerate(states[e])} for e in train_idx + eval_idx)
    text = json.dumps({"version": STATE_VERSION, "data": data, "tasks": [tasks[e] for e in train_idx + eval_idx],
                       "train": train_idx, "evaluated": eval_idx, "robot_dims": robot_dims, "model": asdict(cfg),
                       "gate": asdict(gate)}, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


@dataclass
class _Setup:
    """What both protocols build before training: the ranks, the training windows and statistics, the model and
    its checkpoint (keyed by config + training data)."""

    k: int
    tasks: list[str]
    ranks: np.ndarray
    train_mask: np.ndarray
    train_ds: WindowDataset
    stats: object
    model: WorldModel
    meta: dict
    checkpoint: Path | None

    def model_summary(self) -> dict:
        return {"parameters": self.model.n_parameters(), "state_dim": self.model.state_dim,
                "action_dim": self.model.action_dim, "action_space": self.train_ds.action_space.get("kind")}

    def train_summary(self, summary: dict, device, compile: bool, capture: bool) -> dict:
        return {"steps": summary["steps"], "epochs": summary["epochs"], "seconds": summary["seconds"],
                "frames": summary["frames"], "episodes": int(self.train_mask.sum()),
                "windows_per_epoch": int(len(self.train_ds.windows(0))), "last": summary["last"],
                "device": str(device), "compile": bool(compile), "capture": bool(capture),
                "segments": summary["segments"]}


def _prepare(source, episodes_per_task: int, training: Training, execution: Execution, *,
             eval_episodes: tuple[int, int], eval_context: int | None, protocol: str = "paper",
             loss_robot_margin: int | None = None) -> _Setup:
    """Checks (episodes per task, context, windows per task, frame size) and the objects training needs (of
    `training`: its model, train and window configs; of `execution`: checkpoint_dir, how_to_get_more). The
    checkpoint key is the config + training data (by value: simeval.episodes.digest), and `protocol` for any
    protocol but the paper's (so the paper's checkpoints keep their names). `loss_robot_margin`: None trains on the
    full frame; a margin leaves the robot's pixels (masks grown by it) out of the loss where the episodes carry masks
    (and is then part of the key)."""
    model_cfg, train_cfg, window = training.model, training.train, training.window
    checkpoint_dir, how_to_get_more = execution.checkpoint_dir, execution.how_to_get_more
    infos = source.infos
    tasks, seeds = [i.task for i in infos], [i.seed for i in infos]
    ranks = episode_ranks(tasks, seeds)
    k = int(episodes_per_task)
    if k < 1:
        raise UserError(f"episodes={k}: expected a whole number >= 1 (the paper uses 10, 20, 40)")
    require_ranks(tasks, ranks, max(k, eval_episodes[1]), f"training on {k} and evaluating on episodes "
                                                           f"{eval_episodes[0] + 1}-{eval_episodes[1]}", how_to_get_more)
    check_eval_context(eval_context, window)  # before training, not after it
    train_mask = rank_mask(ranks, 0, k)
    check_every_task_has_windows(infos, train_mask, window, train_cfg.seed, train_cfg.epochs)
    check_frames_not_upsampled(source, model_cfg.image_size)
    train_ds = WindowDataset(source, window, train_mask, image_size=model_cfg.image_size, seed=train_cfg.seed,
                             robot_masks=loss_robot_margin is not None, mask_margin=loss_robot_margin or 0)
    stats = train_ds.fit_stats()
    train_ds.stats = stats
    state_dim, action_dim = len(stats.state_mean), len(stats.action_mean)
    torch.manual_seed(train_cfg.seed)
    model = WorldModel(model_cfg, state_dim, action_dim)
    if model_cfg.pixel_norm != "none":
        from simeval.measures.dynamics_diversity.prediction import pixel_stats

        model.set_pixel_stats(*pixel_stats(source, train_mask, model_cfg.image_size))
    model_key = model_cfg.to_dict()
    if model_cfg.pixel_norm == "none":  # the settings from before pixel_norm existed keep their checkpoints' names
        model_key = {k: v for k, v in model_key.items() if k not in ("pixel_norm", "pixel_std_floor")}
    meta = {"version": VERSION, "model": model_key, "train": asdict(train_cfg), "window": asdict(window),
            "episodes_per_task": k, "data": data_fingerprint([i for i, m in zip(infos, train_mask) if m]),
            "stats": stats.to_dict(), "state_dim": state_dim, "action_dim": action_dim,
            "action_space": train_ds.action_space}
    if protocol != "paper":
        meta["protocol"] = protocol
    if train_ds.robot_masks:
        meta["loss_excludes_robot_grown_by"] = int(loss_robot_margin)
    meta["content"] = source_digest(source, train_mask, train_ds.robot_masks)
    checkpoint = None
    if checkpoint_dir is not None:
        key = hashlib.sha1(json.dumps(meta, sort_keys=True, default=str).encode()).hexdigest()[:16]
        checkpoint = Path(checkpoint_dir) / f"world_model-{key}.pt"
    return _Setup(k, tasks, ranks, train_mask, train_ds, stats, model, meta, checkpoint)


def prediction_videos(model: WorldModel, dataset: WindowDataset, context: int, seed: int = 0,
                      n_tasks: int | None = None) -> dict[str, np.ndarray]:
    """{task: open_loop_video(...)} for the first `n_tasks` tasks by name (all when None): each task's first window
    (its earliest start) of its first episode by seed among the dataset's episodes, a fixed choice, so runs that
    differ in training data show the same windows. The same `seed` as the evaluation gives its samples."""
    infos, windows = dataset.source.infos, dataset.windows(0)
    first: dict[str, tuple[int, int]] = {}  # task -> (episode, start)
    for e, start in sorted((int(e), int(s)) for e, s in windows):
        task, held = infos[e].task, first.get(infos[e].task)
        if held is None or (infos[e].seed, start) < (infos[held[0]].seed, held[1]):
            first[task] = (e, start)
    chosen = sorted(first)[:n_tasks] if n_tasks is not None else sorted(first)
    return {task: open_loop_video(model, dataset[first[task]], context, seed=seed) for task in chosen}


def how_to_get_episodes(store: str | Path, pipeline: str, group: str, suite: str | None, episodes: int,
                        extra: str = "", own_code: str | None = None) -> str:
    """The command that collects `episodes` per task of the group into `store` (the collector writes where this run
    reads, not to its own default), or, for a pipeline without a simeval suite, how to import them. `extra`:
    overrides the collector needs too, e.g. " debug=tiny" (the recording settings it implies must match).
    `own_code`: for a pipeline whose own code records its episodes (GenSim's checkout, Meta-World), the arguments
    its collect command needs beyond pipeline= (simeval.pipelines.registry.own_code_args: " pipeline.root=<checkout>"
    for GenSim's); None for a simeval suite.
    Episodes of the pipeline already in the store at another frame size than the collector's default make the
    command say that size too (record.image_size=...), since the collector refuses to mix sizes in one store."""
    extra += _stored_size_override(store, pipeline, extra)
    if own_code is not None:
        return (f"collect them with the pipeline's own code: python src/collect.py pipeline={pipeline}{own_code} "
                f"task_group={group} episodes={episodes} store={store}{extra}")
    if not suite:
        return (f"pipeline={pipeline} has no simeval suite (pipeline.suite is null): import its episodes into the "
                "store with src/import_data.py")
    from simeval.sim.tasks.spec import suite_dir, load_suite

    specs = load_suite(suite_dir(suite))
    groups = sorted({s.group for s in specs})
    into = f" store={store}{extra}"
    if group in groups or group == "all":
        # a store collected with tasks=[...] gets those tasks again, not the whole group: that would change what
        # the next reading reads
        stored = stored_tasks(store, pipeline, group)
        which = f"'tasks=[{','.join(stored)}]'" if stored and set(stored) < {
            s.name for s in specs if group in ("all", s.group)} else f"task_group={group}"
        return f"collect them: python src/collect.py pipeline={pipeline} {which} episodes={episodes}{into}"
    return (f"the {suite} suite's groups are {', '.join(groups)} (collect one with python src/collect.py "
            f"pipeline={pipeline} task_group={groups[0]} episodes={episodes}{into}), or import episodes of yours")


def stored_tasks(store: str | Path, pipeline: str, group: str) -> list[str]:
    """The tasks of a pipeline's group (`all`: every group) that the store holds episodes of, from the files it can
    read (a damaged one is skipped: the caller's error names it); [] without a store."""
    from simeval.episodes.store import EpisodeStore, read_meta

    if not Path(store).is_dir():
        return []
    tasks = set()
    for path in EpisodeStore(store).paths(pipeline):
        try:
            meta = read_meta(path)
        except (UserError, OSError):  # EpisodeFormatError is a UserError
            continue
        if group in ("all", meta["group"]):
            tasks.add(str(meta["task"]))
    return sorted(tasks)


COLLECT_DEFAULTS = {"record.image_size": [64, 64], "record.cameras": ["front", "top"]}  # conf/collect.yaml's


def _stored_size_override(store: str | Path, pipeline: str, extra: str) -> str:
    """` record.image_size=[H,W]` and ` record.cameras=[...]` where the store's first episode of `pipeline` was
    recorded otherwise than conf/collect.yaml's defaults (COLLECT_DEFAULTS) and `extra` does not already settle it
    (a debug overlay or the key itself): the collector refuses to mix recordings in one store."""
    from simeval.episodes.store import EpisodeStore, read_recording

    try:
        first = next(iter(EpisodeStore(store).paths(pipeline)), None)
        recorded = read_recording(first) if first is not None else {}
    except (UserError, OSError):  # a damaged file is reported by the caller's own error
        return ""
    out = ""
    size, cameras = recorded.get("record.image_size"), recorded.get("record.cameras")
    if size and list(size) != COLLECT_DEFAULTS["record.image_size"] and not (
            "debug=" in extra or "record.image_size" in extra):
        out += f" 'record.image_size=[{size[0]},{size[1]}]'"
    if cameras and sorted(cameras) != COLLECT_DEFAULTS["record.cameras"] and "record.cameras" not in extra:
        out += f" 'record.cameras=[{','.join(cameras)}]'"
    return out


def store_source(store: str | Path, pipeline: str, group: str, camera: str | None, suite: str | None,
                 episodes_needed: int = 40, collect_extra: str = "", own_code: str | None = None):
    """The episodes of a pipeline's group in the store, or a UserError saying what is missing and how to get it
    (`suite`: the pipeline's simeval suite, whose groups a collect command may name; None when it has none;
    `episodes_needed` per task, for that command; `camera` None: no frame is read, for the state reading alone).
    A damaged file is named: collecting again moves it aside and makes it anew."""
    from simeval.episodes.dataset import StoreSource, store_paths_for
    from simeval.episodes.episode import EpisodeFormatError

    if Path(store).exists() and not Path(store).is_dir():  # collecting "into" it would fail the same way
        raise UserError(f"store={store}: is a file, not a folder; give the episode store's folder "
                        "(default outputs/episodes)")
    try:
        paths = store_paths_for(store, pipeline, group)
    except EpisodeFormatError as e:
        how = how_to_get_episodes(store, pipeline, group, suite, episodes_needed, collect_extra, own_code)
        raise UserError(f"{e}; collecting again moves it aside and makes it anew: {how.removeprefix('collect them: ')}"
                        ) from None
    except UserError as e:
        how = how_to_get_episodes(store, pipeline, group, suite, episodes_needed, collect_extra, own_code)
        raise UserError(f"{e}; {how}") from None
    return StoreSource(paths, camera)


def episode_source(store: str | Path, pipeline: str, group: str, camera: str | None, *, suite: str | None,
                   own_code: str | None, episodes_needed: int, debug_overlay: str = "none", collect_extra: str = ""):
    """(store_source's episodes, how_to_get_more(n): the command that collects n per task): what src/diversity.py
    reads, and tells a user to run when there are too few. `debug_overlay`: the run's debug= choice, which the
    collect command repeats (its recording settings must match the run's); `collect_extra`: more arguments it
    repeats (a plugin pipeline's `hydra.searchpath=[...]`)."""
    extra = (f" debug={debug_overlay}" if debug_overlay != "none" else "") + collect_extra
    source = store_source(store, pipeline, group, camera, suite, episodes_needed, extra, own_code)
    return source, lambda n: how_to_get_episodes(store, pipeline, group, suite, n, extra, own_code)


def tasks_not_stored(tasks_read, group: str, suite: str | None) -> list[str]:
    """The tasks of a simeval suite's `group` (`all`: every group) that are not among `tasks_read` (a store
    collected with tasks=[...]): a reading of part of a group, which the run says beside its numbers. [] for a
    pipeline without a suite (its group is whatever its episodes hold)."""
    if not suite:
        return []
    from simeval.sim.tasks.spec import load_suite, suite_dir

    names = {s.name for s in load_suite(suite_dir(suite)) if group in ("all", s.group)}
    return sorted(names - {str(t) for t in tasks_read})


def load_model(checkpoint: str | Path, device: str | torch.device | None = "auto") -> tuple[WorldModel, dict]:
    """A trained model on `device` and the meta (config, stats, data fingerprint) its checkpoint carries. The
    checkpoint is read onto the CPU and then moved, so one trained on a GPU loads anywhere."""
    device = resolve_device(device)
    ck = load_checkpoint(checkpoint)
    meta = ck["meta"]
    model = WorldModel(WorldModelConfig.from_dict(meta["model"]), meta["state_dim"], meta["action_dim"])
    model.load_state_dict(ck["model"])
    return model.to(device), meta


def headline(values: dict) -> dict:
    """The numbers a logger shows for a run: the paper protocol's eval floats, or the heldout protocol's errors and
    skill scores (one step, open loop, reconstruction)."""
    if "prediction" not in values:
        return {"eval": {k: v for k, v in values["eval"].items() if isinstance(v, float)}}
    out = {}
    for kind, block in (values["prediction"] or {"summary": {}})["summary"].items():
        for name, v in block.items():
            if isinstance(v, dict):  # a predictor: model, last, mean
                out.update({f"{kind}/{name}_{k}": x for k, x in v.items() if isinstance(x, float)})
            elif isinstance(v, float):  # a skill score
                out[f"{kind}/{name}"] = v
    if values.get("gate") is not None:  # 1: the numbers read; 0: no reading (the dashboard's filter)
        out["gate/passes"] = float(values["gate"]["passes"])
    state = values.get("state") or {}
    if state.get("gate") is not None:
        out["state/gate_passes"] = float(state["gate"]["passes"])
        out.update({f"state/{k}": v for k, v in state["summary"].items() if isinstance(v, float)})
        for name, beside in (("robot", (state.get("parts") or {}).get("robot")), ("whole", state.get("whole_state"))):
            if beside:  # version 5 reads the objects; the robot's and the whole state's are charted beside
                out.update({f"state_{name}/{k}": v for k, v in beside["summary"].items() if isinstance(v, float)})
    return {"heldout": out}


def readings(values: dict) -> dict[str, str]:
    """What a heldout run's two readings are, before any of their numbers: {"pixels": ..., "state": ...}, each
    "reads" (its gate passed: its numbers read the group's dynamics), the gate's "no reading: <why>" (its numbers
    are there, and are no reading of anything) or "not read (<the setting>)"."""
    gate, state = values.get("gate"), values.get("state")
    pixels = ("not read (protocol.pixels=false)" if values.get("prediction") is None else
              gate["verdict"] if gate else "no gate (a run recorded before it)")
    if not state:
        return {"pixels": pixels, "state": "not read (protocol.state_model=null)"}
    if not state.get("gate"):
        return {"pixels": pixels, "state": state["line"]}
    what = {"objects": "objects' poses", "state": "whole state"}.get(state.get("reads"))
    return {"pixels": pixels, "state": (f"{what}: " if what else "") + state["gate"]["verdict"]}


def summary_line(values: dict) -> str:
    """One log line of a run's result (both protocols)."""
    if "prediction" not in values:
        e = values["eval"]
        return (f"eval error {e['image_error']:.2f} ({e['image_error_per_pixel']:.5f} per pixel), state "
                f"{e['state_error']:.3f}, KL {e['kl_dyn']:.2f}, open-loop {e['open_loop_image_error']:.2f}")
    if values["prediction"] is None:  # protocol.pixels=false
        return f"held-out episodes {values['protocol']['evaluated_on']}: state reading: {values['state']['line']}"
    p = values["prediction"]["summary"]
    f = lambda x: "n/a" if x is None else f"{x:.2f}"  # noqa: E731
    verdict = values.get("gate", {}).get("verdict")  # runs recorded before the gate have none
    if verdict is not None and verdict != "reads":  # the numbers are no reading of diversity: none in their place
        return (f"held-out episodes {values['protocol']['evaluated_on']}: pixel reading: {verdict}"
                + (f"; state reading: {values['state']['line']}" if values.get("state") else ""))
    ol, one = p["open_loop"], p["one_step"]
    milli = lambda x: "n/a" if x is None else f"{1e3 * x:.3f}"  # noqa: E731
    trained = values["protocol"].get("robot_excluded_from_loss")
    return (f"held-out episodes {values['protocol']['evaluated_on']}: "
            + ("pixel reading (the gate: the model beats both baselines): " if verdict else "")
            + "object-focused one-step error (primary, "
            f"x1e-3 per pixel) {milli(one['model']['object_error_per_pixel'])} (last frame "
            f"{milli(one['last']['object_error_per_pixel'])}, mean image {milli(one['mean']['object_error_per_pixel'])}"
            f"{'; robot not trained on' if trained else ''}); open-loop error {f(ol['model']['error'])} (last "
            f"frame {f(ol['last']['error'])}, mean image {f(ol['mean']['error'])}; skill {f(ol['skill_vs_last'])} / "
            f"{f(ol['skill_vs_mean'])}), one-step {f(one['model']['error'])} (skill vs last frame "
            f"{f(one['skill_vs_last'])}), reconstruction {f(p['reconstruction']['model']['error'])}; moving pixels "
            + (f"({100 * one['moving_share']:.2g}% of kept) one-step {milli(one['model']['moving_error_per_pixel'])} "
               f"x1e-3 (skill vs last frame {f(one['moving_skill_vs_last'])})" if one.get("moving_share") else "none")
            + ("" if values["prediction"]["robot_mask"] else "; no robot masks: object-focused = full frame")
            + (f"; state reading: {values['state']['line']}" if values.get("state") else ""))


def ranks_of(value, key: str) -> tuple[int, int] | None:
    """A config's [first, last] 1-based inclusive episode numbers as 0-based (lo, hi), None for None; anything else
    is a UserError naming `key`."""
    if value is None:
        return None
    bounds = list(value) if isinstance(value, (list, tuple)) else [value]
    if len(bounds) != 2 or not all(isinstance(b, int) and not isinstance(b, bool) for b in bounds):
        raise UserError(f"{key}={value!r}: expected [first, last] episode numbers, e.g. {key}=[1,40]")
    lo, hi = bounds
    if not 1 <= lo <= hi:
        raise UserError(f"{key}={list(value)}: expected [first, last] episode numbers, 1 <= first <= last")
    return lo - 1, hi


@dataclass(frozen=True)
class DiversityRun:
    """What one run of src/diversity.py measures, in plain values (conf/diversity.yaml's keys): `world_model` is
    the preset ({name, model, train, window}), `protocol` the protocol section ({name, steps, horizon, lr, ...}),
    `evaluation` the eval section ({seed, context, batch_size})."""

    pipeline: str
    task_group: str
    camera: str
    episodes: int
    seed: int
    world_model: dict
    protocol: dict
    evaluation: dict
    eval_episodes: tuple[int, int] | None
    heldout_episodes: tuple[int, int] | None

    @classmethod
    def from_config(cls, conf: Mapping) -> DiversityRun:
        """The run conf/diversity.yaml describes (as a plain mapping: the run's resolved config)."""
        return cls(pipeline=conf["pipeline"]["name"], task_group=conf["task_group"], camera=conf["camera"],
                   episodes=int(conf["episodes"]), seed=int(conf["seed"]), world_model=conf["world_model"],
                   protocol=conf["protocol"], evaluation=conf["eval"],
                   eval_episodes=ranks_of(conf["eval_episodes"], "eval_episodes"),
                   heldout_episodes=ranks_of(conf["heldout_episodes"], "heldout_episodes"))

    @cached_property
    def configs(self) -> tuple[WorldModelConfig, TrainConfig, WindowSpec]:
        """The model, training and window configs, every protocol value checked (once; read it before any data is
        read so a bad value stops there)."""
        heldout = self.protocol["name"] == "heldout"  # its model settings (pixel_norm) over the preset's
        model_cfg = WorldModelConfig.from_dict({**self.world_model["model"],
                                                **((self.protocol.get("model") or {}) if heldout else {})})
        train_cfg = TrainConfig.from_dict({**self.world_model["train"], "seed": int(self.seed)})
        window = WindowSpec(**self.world_model["window"])
        check_eval_context(int(self.evaluation["context"]), window)
        ignored = [k for k in HELDOUT_ONLY if k in self.protocol] if self.protocol["name"] != "heldout" else []
        if ignored:  # given with '+': the run would go on without them
            raise UserError(f"protocol.{ignored[0]}: a setting of protocol=heldout, which protocol="
                            f"{self.protocol['name']} does not read (it has no gate, state reading or pixel "
                            "standardisation); drop it, or run it with protocol=heldout alone (not in a sweep over "
                            "both protocols)")
        if self.protocol["name"] == "heldout":
            check_heldout_settings(self.protocol["steps"], self.protocol["horizon"], self.protocol["lr"],
                                   self.mask_margin, int(self.evaluation["context"]), self.exclude_robot)
            GateConfig.from_dict(self.protocol.get("gate"))
            if self.protocol.get("state_model") is not None:
                StateModelConfig.from_dict(self.protocol["state_model"])
            if not isinstance(self.pixels, bool):
                raise UserError(f"protocol.pixels={self.pixels!r}: expected true (the world model's reading beside "
                                "the state one) or false (the state reading only)")
            if not self.pixels and self.protocol.get("state_model") is None:
                raise UserError("protocol.pixels=false with protocol.state_model=null: the run would read nothing")
        return model_cfg, train_cfg, window

    @property
    def pixels(self):  # protocol=heldout: whether the world model is trained and read (else the states only)
        return self.protocol.get("pixels", True) if self.protocol["name"] == "heldout" else True

    @property
    def episodes_needed(self) -> int:
        """Episodes per task the run reads: its training ones and its evaluated ones (protocol=paper's held-out
        episodes are optional, so they do not count). Checks every setting first (configs)."""
        _ = self.configs
        return max(int(self.episodes), (self.eval_episodes or (0, 40))[1])

    def describe(self, device, values: dict) -> str:
        """The run's one-line result for the log."""
        if not self.pixels:  # no world model: its preset and device say nothing of this run
            return (f"{self.pipeline}/{self.task_group} episodes={self.episodes} [protocol=heldout, states only]: "
                    f"{summary_line(values)}")
        return (f"{self.pipeline}/{self.task_group} episodes={self.episodes} [preset {self.world_model['name']}, "
                f"device {device}, protocol={self.protocol['name']}]: {summary_line(values)}")

    @property
    def mask_margin(self) -> int:  # protocol=paper leaves it null: no robot masks in its score or loss
        return self.protocol.get("mask_margin", 0) if self.protocol["name"] == "heldout" else 0

    @property
    def exclude_robot(self) -> bool:
        return self.protocol.get("exclude_robot_from_loss", False) if self.protocol["name"] == "heldout" else False

    def identity(self, source) -> dict:
        """What the numbers are of (simeval.results.make_identity); the paper protocol's is what it always was, so
        earlier runs still match theirs."""
        ident = dict(pipeline=self.pipeline, task_group=self.task_group, episodes=int(self.episodes),
                     preset=self.world_model["name"], camera=self.camera, episodes_sha=data_fingerprint(source.infos),
                     settings={"world_model": self.world_model, "eval": self.evaluation,
                               "eval_episodes": None if self.eval_episodes is None else
                               [self.eval_episodes[0] + 1, self.eval_episodes[1]]})
        if self.protocol["name"] != "paper":
            ident.update(protocol=self.protocol["name"], steps=self.protocol["steps"])
            ident["settings"]["protocol"] = self.protocol
        return ident

    def fit(self, source, execution: Execution, logger, *, videos: int = 0, video_dir: str | None = None) -> dict:
        """fit_and_evaluate with this run's settings, executed as `execution` says (its log_metrics: the logger's
        when it has none); the open-loop videos go to the logger too."""
        model_cfg, train_cfg, window = self.configs
        paper = self.protocol["name"] == "paper"
        training = Training(model_cfg, train_cfg, window, steps=self.protocol.get("steps"), lr=self.protocol.get("lr"),
                            exclude_robot_from_loss=self.exclude_robot)
        evaluation = Evaluation(
            protocol=self.protocol["name"], episodes=self.eval_episodes,
            heldout_episodes=self.heldout_episodes if paper else None, seed=int(self.evaluation["seed"]),
            context=int(self.evaluation["context"]), batch_size=int(self.evaluation["batch_size"]),
            horizon=self.protocol.get("horizon"), mask_margin=self.mask_margin,
            gate=None if paper else GateConfig.from_dict(self.protocol.get("gate")),
            state_model=None if paper or self.protocol.get("state_model") is None else
            StateModelConfig.from_dict(self.protocol["state_model"]), pixels=self.pixels, videos=videos,
            video_dir=video_dir)
        if execution.log_metrics is None:
            execution = replace(execution, log_metrics=logger.log_metrics)
        values = fit_and_evaluate(source, int(self.episodes), training, evaluation, execution)
        for task, video in values["videos"].items():
            logger.log_video(f"open_loop/{task}", video, fps=VIDEO_FPS, caption=(
                f"{task}: ground truth | reconstruction | open loop after {int(self.evaluation['context'])} observed "
                "frames (red separators: imagined)"))
        return values
