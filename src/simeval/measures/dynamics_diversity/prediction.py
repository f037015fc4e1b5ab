"""Held-out prediction error of a world model, beside trivial baselines on the same frames (the `heldout` protocol
of dynamics diversity; simeval.measures.dynamics_diversity.run).

Shapes: a batch of B evaluation windows of L rows (simeval.episodes.dataset), images o (B, L, H, W, 3) in [0, 1],
optional robot masks m (B, L, H, W) (True where the robot, its gripper or tool is seen). D is the image decoder,
se(x, y) the squared error summed over the 3 channels (per pixel, (H, W)). Two sets of windows cut the held-out
episodes from row 0 without overlap: windows of the training window's length for the one-step error and the
reconstruction (the history the model was trained to use; so they do not depend on the open-loop horizon), and
windows of context + horizon rows for the open loop.

    one step        for every window step t >= 1 whose rows t - 1 and t are real (t is never a reset inside a
                    window: windows never cross episodes):
                        model  se(D(prior_t), o_t)   the prior at t is the RSSM step from the posterior at t - 1 and
                                                     the action a_{t-1} alone: o_t is predicted before it is seen
                        last   se(o_{t-1}, o_t)      copy the last observed frame
                        mean   se(mu_task, o_t)      the per-task mean of the training episodes' frames
                    reference frame r = t - 1
    open loop       observe rows 0..c-1 (c = context), imagine rows c..L-1 from the actions alone; for every real row
                    c + j (j < horizon) while row c - 1 is real:
                        model  se(D(imagined_{c+j}), o_{c+j});  last  se(o_{c-1}, o_{c+j});  mean  se(mu_task, o_{c+j})
                    reference frame r = c - 1
    reconstruction  se(D(posterior_t), o_t) for every real row: the paper's Table 4 quantity (o_t is observed, so it
                    measures an autoencoder as much as dynamics); mean as its baseline (copying o_t would be exact)

Full frame: the sum over all H x W pixels (units of the paper's "eval error": a sum over H x W x 3). Object-focused:
the sum over the pixels where the robot is seen neither in the target frame nor in the reference frame (nor, for
the reconstruction, in the target), divided by the number of such pixels times 3 (a mean per kept pixel and
channel), so frames where the arm covers more of the view count no more. Without robot masks the object-focused
numbers are the full frame's (per pixel) and `robot_mask` in the summary is False.

Moving (one step and open loop): the kept pixels whose true colour changed from the reference frame,
se(o_r, o_t) > MOTION_THRESHOLD, per moving pixel and channel: what moved outside the robot (a drawer, a pushed or
placed object, a falling one). Static pixels, where the object-focused error only reads how well the model redraws
the scene, count nowhere here; the last frame scores each moving pixel at least the threshold, so a model's skill
against it reads whether it predicts the motion. The pixels are chosen by the truth alone: a model that blurs
change everywhere gains here and loses on the still pixels, so read it beside the object-focused error. Where
fewer than MIN_MOVING_PIXELS kept pixels move over all the frames summed (a top camera over a suction gripper
hides the block it carries) the moving errors and skills are None and `moving_share` (moving / kept pixels) says
why. Why a threshold and not > 0: frames are 8-bit, so a resized or re-lit static pixel may differ by a few levels.

Aggregates are ratios of sums over frames: error = sum se / frames; skill vs a baseline = 1 - error_model /
error_baseline (> 0: better than the baseline; < 0: worse than a constant image or a copy). Per episode the sums are
kept (`per_episode`), so intervals can resample held-out episodes and training seeds (simeval.stats.resample).
"""

from __future__ import annotations

import numpy as np
import torch

from simeval.runtime.device import module_device, to_cpu, to_device

KINDS = ("one_step", "open_loop", "reconstruction")
PREDICTORS = {"one_step": ("model", "last", "mean"), "open_loop": ("model", "last", "mean"),
              "reconstruction": ("model", "mean")}
MOVING_KINDS = ("one_step", "open_loop")  # the reconstruction's reference is its target: nothing moves
MOTION_THRESHOLD = 0.01  # se over the 3 channels in [0, 1]: e.g. one channel off by 0.1 (26 of 255 levels)
MIN_MOVING_PIXELS = 100  # fewer moving pixels (summed over frames) give no moving-pixel reading: a few would be noise
# per (kind, predictor): se over the full frame, over kept (object) pixels, over moving kept pixels; per kind:
# frames, kept pixels, moving pixels
SUM_KEYS = tuple(f"{k}/{p}/{part}" for k in KINDS for p in PREDICTORS[k]
                 for part in ("full", "object") + (("moving",) if k in MOVING_KINDS else ())) + tuple(
    f"{k}/{n}" for k in KINDS for n in ("frames", "kept_pixels") + (("moving_pixels",) if k in MOVING_KINDS else ()))


def _se(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return (x - y).pow(2).sum(-1)  # (..., H, W)


def _add(out: dict, kind: str, predictor: str, se: torch.Tensor, valid: torch.Tensor, keep: torch.Tensor,
         moving: torch.Tensor | None = None) -> None:
    """se (B, T, H, W), valid (B, T) bool, keep and moving (B, T, H, W) float: per-window sums (B,) into out."""
    v = valid.to(se.dtype)
    out[f"{kind}/{predictor}/full"] = (se.sum((-2, -1)) * v).sum(1)
    out[f"{kind}/{predictor}/object"] = ((se * keep).sum((-2, -1)) * v).sum(1)
    if moving is not None:
        out[f"{kind}/{predictor}/moving"] = ((se * moving).sum((-2, -1)) * v).sum(1)


def _count(out: dict, kind: str, valid: torch.Tensor, keep: torch.Tensor,
           moving: torch.Tensor | None = None) -> None:
    v = valid.to(keep.dtype)
    out[f"{kind}/frames"] = v.sum(1)
    out[f"{kind}/kept_pixels"] = (keep.sum((-2, -1)) * v).sum(1)
    if moving is not None:
        out[f"{kind}/moving_pixels"] = (moving.sum((-2, -1)) * v).sum(1)


def _moving(keep: torch.Tensor, last_se: torch.Tensor) -> torch.Tensor:
    """The kept pixels whose true colour changed from the reference frame (last_se: se(o_r, o_t))."""
    return keep * (last_se > MOTION_THRESHOLD).to(keep.dtype)


def _frames(model, batch: dict, task_means: torch.Tensor):
    image = model._images(batch)  # (B, L, H, W, 3)
    robot = batch.get("robot_mask")
    free = torch.ones(image.shape[:-1], dtype=image.dtype, device=image.device) if robot is None else \
        (~robot.bool()).to(image.dtype)  # (B, L, H, W): 1 where no robot is seen
    return image, batch["mask"].bool(), free, task_means[batch["task"]][:, None]  # mean: (B, 1, H, W, 3)


@torch.no_grad()
def step_sums(model, batch: dict, task_means: torch.Tensor, generator=None) -> dict[str, torch.Tensor]:
    """Per-window sums (B,) of the one_step and reconstruction entries of SUM_KEYS (see the module docstring).
    `batch`: the dataset's arrays as tensors on the model's device (image uint8, state, prev_action, is_first, mask,
    optional robot_mask), plus `task` (B,) long indexing `task_means` (n_tasks, H, W, 3) in [0, 1]."""
    image, mask, free, mean = _frames(model, batch, task_means)
    post, prior = model.rssm.observe(model.embed(image, batch["state"]), batch["prev_action"], batch["is_first"],
                                     generator=generator)
    out: dict[str, torch.Tensor] = {}
    _add(out, "reconstruction", "model", _se(model.image_decoder(model.rssm.features(post)), image), mask, free)
    _add(out, "reconstruction", "mean", _se(mean, image), mask, free)
    _count(out, "reconstruction", mask, free)
    # one step: rows 1..L-1 whose previous row is real (and that are not a reset)
    target, prev = image[:, 1:], image[:, :-1]
    valid = mask[:, 1:] & mask[:, :-1] & ~batch["is_first"][:, 1:].bool()
    keep = free[:, 1:] * free[:, :-1]
    last_se = _se(prev, target)
    moving = _moving(keep, last_se)
    _add(out, "one_step", "model", _se(model.image_decoder(model.rssm.features(prior))[:, 1:], target), valid, keep,
         moving)
    _add(out, "one_step", "last", last_se, valid, keep, moving)
    _add(out, "one_step", "mean", _se(mean, target), valid, keep, moving)
    _count(out, "one_step", valid, keep, moving)
    return out


@torch.no_grad()
def open_loop_sums(model, batch: dict, context: int, task_means: torch.Tensor,
                   generator=None) -> dict[str, torch.Tensor]:
    """Per-window sums (B,) of the open_loop entries of SUM_KEYS, and per imagined step (horizon,) summed over the
    windows: open_loop/model/by_step, open_loop/last/by_step, open_loop/frames_by_step. Rows c..L-1 are imagined
    after observing rows 0..c-1 (the generator draws the context's samples, then imagination's)."""
    image, mask, free, mean = _frames(model, batch, task_means)
    _, imagined = model._open_loop(image, batch, context, generator)
    target, ref = image[:, context:], image[:, context - 1 : context]
    valid = mask[:, context:] & mask[:, context - 1 : context]
    keep = free[:, context:] * free[:, context - 1 : context]
    out: dict[str, torch.Tensor] = {}
    model_se, last_se = _se(model.image_decoder(model.rssm.features(imagined)), target), _se(ref, target)
    moving = _moving(keep, last_se)
    _add(out, "open_loop", "model", model_se, valid, keep, moving)
    _add(out, "open_loop", "last", last_se, valid, keep, moving)
    _add(out, "open_loop", "mean", _se(mean, target), valid, keep, moving)
    _count(out, "open_loop", valid, keep, moving)
    out["open_loop/model/by_step"] = (model_se.sum((-2, -1)) * valid).sum(0)
    out["open_loop/last/by_step"] = (last_se.sum((-2, -1)) * valid).sum(0)
    out["open_loop/frames_by_step"] = valid.to(image.dtype).sum(0)
    return out


def _frames_at(source, episodes: np.ndarray, image_size: int):
    """(episode, its frames (n, S, S, 3) uint8) for every episode where `episodes` is True, resized as the dataset
    resizes them."""
    from simeval.episodes.dataset import resize_frames

    for e in np.flatnonzero(episodes):
        frames = source.read_full(int(e), "image")
        yield int(e), frames if frames.shape[1] == image_size else resize_frames(frames, image_size)


def task_mean_images(source, episodes: np.ndarray, image_size: int) -> dict[str, np.ndarray]:
    """{task: (H, W, 3) float32 in [0, 1]}: the mean of every frame of the task's episodes where `episodes` is True
    (the training episodes), at the model's resolution (frames resized as the dataset resizes them)."""
    sums: dict[str, np.ndarray] = {}
    counts: dict[str, int] = {}
    for e, frames in _frames_at(source, episodes, image_size):
        task = source.infos[e].task
        sums[task] = sums.get(task, 0.0) + frames.astype(np.float64).sum(0)
        counts[task] = counts.get(task, 0) + len(frames)
    return {t: (sums[t] / counts[t] / 255.0).astype(np.float32) for t in sorted(sums)}


def pixel_stats(source, episodes: np.ndarray, image_size: int) -> tuple[np.ndarray, np.ndarray]:
    """(mean, deviation), each (H, W, 3) in [0, 1]: over every frame of the episodes where `episodes` is True (the
    training episodes), at the model's resolution (WorldModel.set_pixel_stats)."""
    total, squares, n = 0.0, 0.0, 0
    for _, frames in _frames_at(source, episodes, image_size):
        x = frames.astype(np.float64) / 255.0
        total, squares, n = total + x.sum(0), squares + (x**2).sum(0), n + len(x)
    mean = total / n
    return mean.astype(np.float32), np.sqrt(np.maximum(squares / n - mean**2, 0.0)).astype(np.float32)


def summarise(sums: dict[str, float], image_size: int) -> dict:
    """Errors and skill scores from summed SUM_KEYS (see the module docstring); None where no frame counts."""
    pixels = image_size * image_size
    out: dict = {}
    for kind in KINDS:
        n, kept = sums[f"{kind}/frames"], sums[f"{kind}/kept_pixels"]
        block: dict = {"frames": int(n)}
        for p in PREDICTORS[kind]:
            full = sums[f"{kind}/{p}/full"] / n if n else None
            block[p] = {"error": full, "error_per_pixel": full / (pixels * 3) if n else None,
                        "object_error_per_pixel": sums[f"{kind}/{p}/object"] / (kept * 3) if kept else None}
        count = sums.get(f"{kind}/moving_pixels")  # None: not summed (the reconstruction)
        moving = count if count is not None and count >= MIN_MOVING_PIXELS else 0.0  # fewer: no reading
        for p in PREDICTORS[kind]:
            if kind in MOVING_KINDS:
                block[p]["moving_error_per_pixel"] = sums[f"{kind}/{p}/moving"] / (moving * 3) if moving else None
        if kind in MOVING_KINDS:
            block["moving_share"] = count / kept if kept and count is not None else None
        for base in PREDICTORS[kind][1:]:
            m, b = block["model"], block[base]
            block[f"skill_vs_{base}"] = (1 - m["error"] / b["error"]) if n and b["error"] else None
            # vs a copy of the last frame only where something outside the robot moved: otherwise the copy is exact
            # up to 8-bit noise and the ratio divides by ~0
            readable = kept and b["object_error_per_pixel"] and (base != "last" or kind not in MOVING_KINDS or moving)
            block[f"object_skill_vs_{base}"] = (1 - m["object_error_per_pixel"] / b["object_error_per_pixel"]
                                                if readable else None)
            if kind in MOVING_KINDS:
                block[f"moving_skill_vs_{base}"] = (1 - m["moving_error_per_pixel"] / b["moving_error_per_pixel"]
                                                    if moving and b["moving_error_per_pixel"] else None)
        out[kind] = block
    return out


@torch.no_grad()
def evaluate_prediction(model, step_dataset, open_loop_dataset, task_means: dict[str, np.ndarray], context: int,
                        seed: int = 0, batch_size: int = 16, progress: bool = False) -> dict:
    """Every window of `step_dataset` (held-out episodes in windows of the training length: one step,
    reconstruction) and of `open_loop_dataset` (the same episodes in windows of context + horizon rows): {summary
    (summarise over everything), per_task, per_episode: [{task, seed, sums}], by_step: {model, last} open-loop error
    per imagined step, robot_mask: whether the episodes had robot masks, context, horizon, windows, seed}. Seeded:
    the same seed gives the same numbers (the one-step pass draws first, then the open-loop pass)."""
    from tqdm.auto import tqdm

    from simeval.models.world_model_training import _loader, to_torch

    model.eval()
    device = module_device(model)
    infos = step_dataset.source.infos
    tasks = sorted(task_means)
    means = torch.as_tensor(np.stack([task_means[t] for t in tasks])).to(device)
    index = {t: i for i, t in enumerate(tasks)}
    horizon = open_loop_dataset.spec.length - context
    gen = torch.Generator().manual_seed(int(seed))
    per_episode: dict[int, dict[str, float]] = {}
    by_step = {"model": np.zeros(horizon), "last": np.zeros(horizon), "frames": np.zeros(horizon)}
    has_masks = step_dataset.robot_masks
    n_windows = 0
    for dataset, sums in ((step_dataset, lambda b: step_sums(model, b, means, generator=gen)),
                          (open_loop_dataset, lambda b: open_loop_sums(model, b, context, means, generator=gen))):
        windows = dataset.windows(0)
        n_windows += len(windows)
        batches = [[(int(e), int(s)) for e, s in windows[i : i + batch_size]]
                   for i in range(0, len(windows), batch_size)]
        for batch in tqdm(_loader(dataset, batches, 0), total=len(batches), desc="eval", disable=not progress,
                          leave=False):
            b = to_torch(batch)
            episodes = b["episode"][:, 0].tolist()
            b["task"] = torch.tensor([index[infos[e].task] for e in episodes])
            s = to_cpu(sums(to_device(b, device, non_blocking=True)))
            for j, e in enumerate(episodes):
                acc = per_episode.setdefault(e, dict.fromkeys(SUM_KEYS, 0.0))
                for k in SUM_KEYS:
                    if k in s:
                        acc[k] += float(s[k][j])
            if "open_loop/model/by_step" in s:
                by_step["model"] += s["open_loop/model/by_step"].numpy()
                by_step["last"] += s["open_loop/last/by_step"].numpy()
                by_step["frames"] += s["open_loop/frames_by_step"].numpy()
    model.train()
    size = int(model.cfg.image_size)
    total = {k: sum(acc[k] for acc in per_episode.values()) for k in SUM_KEYS}
    by_task: dict[str, dict[str, float]] = {}
    for e, acc in per_episode.items():
        t = by_task.setdefault(infos[e].task, dict.fromkeys(SUM_KEYS, 0.0))
        for k in SUM_KEYS:
            t[k] += acc[k]
    with np.errstate(invalid="ignore", divide="ignore"):
        curve = {p: [float(x) if np.isfinite(x) else None for x in by_step[p] / by_step["frames"]]
                 for p in ("model", "last")}
    return {"summary": summarise(total, size), "per_task": {t: summarise(v, size) for t, v in sorted(by_task.items())},
            "per_episode": [{"task": infos[e].task, "seed": int(infos[e].seed), "sums": {k: round(v, 4) for k, v in
                                                                                       acc.items()}}
                            for e, acc in sorted(per_episode.items())],
            "by_step": curve, "robot_mask": bool(has_masks), "context": int(context), "horizon": int(horizon),
            "step_window": int(step_dataset.spec.length), "windows": int(n_windows), "seed": int(seed),
            "image_size": size}
