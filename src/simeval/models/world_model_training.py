"""Training and evaluation of the world model on window datasets (simeval.episodes.dataset), with checkpoints
that carry their config and resume exactly.

Budget: the paper's, a fixed number of epochs over the training windows (`epochs`); `max_steps` caps the gradient
steps instead (or as well). A step is one Adam update on `batch_size` windows, gradients clipped to `clip` (global
norm). Everything random is seeded from `seed`: the window order of epoch e, the per-epoch window offset (in the
dataset), and the latent samples of step i (a generator seeded with (seed, i)). So a run killed and resumed from
its last checkpoint takes the same steps as one never interrupted (on the same machine and thread count).

Device (`device`: auto, cpu, cuda, cuda:N; simeval.runtime.device): the model, Adam's state and each batch live
there; the random draws come from the CPU generators above and are moved, so they do not depend on the device.
Checkpoints hold CPU tensors and not the device: a run started on a GPU resumes on a CPU machine and vice versa.
`compile` (WorldModel.compile_steps) and `capture` (the whole step as one CUDA graph: simeval.runtime.captured) are,
like the device, how a run computes and not what: they are not part of a checkpoint either.

Evaluation (`evaluate`): the model observes each evaluation window with posterior samples from a generator seeded
with `seed` and reports, averaged over all valid evaluation frames:
  image_error            squared error summed over the H x W x 3 pixels in [0, 1] of the posterior reconstruction
                         (the paper's "eval error", Table 4; it scales with the resolution)
  image_error_per_pixel  image_error / (H * W * 3)
  state_error            squared error summed over the state dimensions, in symlog space of the standardised state
  kl_dyn, kl_rep         KL[sg(q) || p] and KL[q || sg(p)] (equal in value; unclipped)
  open_loop_*            the same errors of frames imagined from actions alone after `context` observed frames
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from simeval.errors import UserError, check_field_types, require_whole_fields
from simeval.runtime.checkpoints import read_checkpoint, save_checkpoint
from simeval.runtime.device import module_device, resolve_device, to_cpu, to_device
from simeval.runtime.trainer import duration, refuse_other_settings, run_steps

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = 1


@dataclass
class TrainConfig:
    batch_size: int = 8  # paper: 8
    epochs: int = 10  # paper: 10
    max_steps: int | None = None  # optional cap on gradient steps
    lr: float = 1e-4
    eps: float = 1e-8
    clip: float = 1000.0
    seed: int = 0
    checkpoint_every: int = 200  # steps; also at every epoch end
    num_workers: int = 0  # DataLoader workers reading windows

    def __post_init__(self) -> None:
        check_field_types(self, "world_model.train")
        require_whole_fields(self, "world_model.train", ("batch_size", "epochs", "checkpoint_every"))
        if self.max_steps is not None and (not isinstance(self.max_steps, int) or self.max_steps < 1):
            raise UserError(f"world_model.train.max_steps={self.max_steps!r}: expected null or a whole number >= 1")
        if self.lr <= 0 or self.clip <= 0:
            raise UserError(f"world_model.train.lr={self.lr}, world_model.train.clip={self.clip}: both must be > 0")
        if self.num_workers < 0:
            raise UserError(f"world_model.train.num_workers={self.num_workers}: expected >= 0")

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        if set(d) - known:
            raise UserError(f"train: unknown key(s) {sorted(set(d) - known)}; valid: {sorted(known)}")
        return cls(**d)


def to_torch(batch: dict) -> dict[str, torch.Tensor]:
    return {k: (v if isinstance(v, torch.Tensor) else torch.as_tensor(v)) for k, v in batch.items()}


def collate(items: list[dict]) -> dict[str, torch.Tensor]:
    return {k: torch.from_numpy(np.stack([it[k] for it in items])) for k in items[0]}


def _loader(dataset, batches: list[list[tuple[int, int]]], num_workers: int, pin_memory: bool = False):
    from torch.utils.data import DataLoader

    if num_workers == 0:  # no worker processes: read in the training thread
        return (collate([dataset[i] for i in b]) for b in batches)
    # pin_memory (for a GPU): batches in page-locked memory, whose non_blocking copy can overlap with computation.
    # The start method is named: inside a hydra/launcher=joblib job the default one is loky's, whose Process the
    # DataLoader cannot start (AttributeError: 'Process' object has no attribute 'env'); fork is what it is
    # elsewhere on Linux, and the HDF5-backed dataset is not picklable for spawn.
    import multiprocessing as mp

    context = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    return DataLoader(dataset, batch_sampler=batches, num_workers=num_workers, collate_fn=collate,
                      persistent_workers=False, prefetch_factor=4, pin_memory=pin_memory,
                      multiprocessing_context=context)


def epoch_batches(windows: np.ndarray, batch_size: int, seed: int, epoch: int) -> list[list[tuple[int, int]]]:
    order = np.random.default_rng([seed, epoch, 11]).permutation(len(windows))
    w = windows[order]
    return [[(int(e), int(s)) for e, s in w[i : i + batch_size]] for i in range(0, len(w), batch_size)]


def step_generator(seed: int, step: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(np.random.default_rng([seed, step, 13]).integers(2**62)))


def load_checkpoint(path: str | os.PathLike) -> dict:
    ck = read_checkpoint(path, "world-model")
    if ck.get("format") != CHECKPOINT_FORMAT:
        what = "a policy checkpoint" if "policy_config" in ck else f"format {ck.get('format')!r}"
        raise UserError(f"{path}: not a world-model checkpoint of format {CHECKPOINT_FORMAT} ({what}); delete it "
                        "or use another checkpoint_dir")
    return ck


def train(model, dataset, cfg: TrainConfig, checkpoint: str | os.PathLike | None = None, meta: dict | None = None,
          log_metrics: Callable[[dict, int], None] | None = None, progress: bool = True,
          device: str | torch.device | None = "auto", compile: bool = False, capture: bool = False) -> dict:
    """Train in place on `device` (the model is moved there; with `compile`, its steps are compiled: see
    WorldModel.compile_steps); return {steps, epochs, seconds, frames, segments, last: metrics}, where seconds and
    frames count the whole training, the parts before a resume included, and segments says how each part was
    trained: [{steps: [first, end), device, compile, capture}] (None for what a part written before checkpoints
    recorded them). With `checkpoint`, resume from it when it exists and its `meta` (config, data identity; not the
    device) matches, and save to it every `checkpoint_every` steps and at each epoch end. `meta` is stored in the
    checkpoint (the config that made it)."""
    from simeval.runtime.captured import capture_needs_cuda

    device = resolve_device(device)
    if capture and device.type != "cuda":
        raise capture_needs_cuda(f"the device is {device}")
    run = _Training(model, dataset, cfg, checkpoint, dict(meta or {}), log_metrics=log_metrics, progress=progress,
                    device=device, compile=compile, capture=capture)
    step = run_steps(run.window_batches(), run.take_step, run.save, step=run.first_step,
                     checkpoint_every=cfg.checkpoint_every, after_step=run.after_step,
                     final_save=lambda s: run.save(s, finished=True))
    return {"steps": step, "epochs": run.epoch, "seconds": run.seconds_before + time.perf_counter() - run.t0,
            "segments": run.trained_by(step), "frames": run.frames_before + run.frames, "last": run.last}


class _Training:
    """One process's part of a training: the model and its optimiser on `device`, where it resumes (the
    checkpoint's epoch, batch and step), and what it has done since; `train` drives it with run_steps (which
    checkpoints at a preemption signal as well as on the cadence)."""

    def __init__(self, model, dataset, cfg: TrainConfig, checkpoint, meta: dict, *, log_metrics, progress: bool,
                 device: torch.device, compile: bool, capture: bool) -> None:
        from simeval.runtime.captured import CapturedTrainStep

        self.model, self.dataset, self.cfg, self.meta = model, dataset, cfg, meta
        self.checkpoint, self.log_metrics, self.progress = checkpoint, log_metrics, progress
        self.device, self.compile, self.capture = device, compile, capture
        model.to(device)  # before Adam is made: its state is created beside the parameters
        if compile:
            model.compile_steps()
        self.opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, eps=cfg.eps)
        self.epoch, self.batch, self.first_step = 0, 0, 0  # the next batch's position: what a checkpoint resumes
        self.frames_before, self.seconds_before = 0, 0.0  # what earlier processes trained (reported as one run)
        self.segments: list[dict] = []  # how earlier processes trained: [{steps: [first, end), device, compile}]
        if checkpoint is not None and Path(checkpoint).is_file():
            self._resume()
        model.train()
        self.captured = CapturedTrainStep(model, self.opt, cfg.clip) if capture else None
        self.t0, self.frames, self.last = time.perf_counter(), 0, {}

    def _resume(self) -> None:
        ck = load_checkpoint(self.checkpoint)
        refuse_other_settings(self.checkpoint, ck["meta"], self.meta, "run folder")
        self.model.load_state_dict(ck["model"])  # copies the checkpoint's CPU tensors into the parameters
        self.opt.load_state_dict(ck["optimizer"])  # torch moves the state to its parameters' device
        self.epoch, self.batch, self.first_step = ck["epoch"], ck["batches_done"], ck["step"]
        self.frames_before, self.seconds_before = int(ck.get("frames", 0)), float(ck.get("seconds", 0.0))
        step = self.first_step
        self.segments = list(ck.get("segments") or ([{"steps": [0, step], "device": None, "compile": None}]
                                                    if step else []))
        if ck.get("finished"):  # a finished run only evaluates: "resumed" would say it trains on
            log.info("trained already (%d steps): %s; evaluating only", step, self.checkpoint)
        else:
            # counted from 1, as the per-epoch lines count: it goes on at this epoch's batch
            log.info("resumed from %s at epoch %d, batch %d (step %d)", self.checkpoint, self.epoch + 1,
                     self.batch + 1, step)

    def trained_by(self, step: int) -> list[dict]:
        here = {"steps": [self.first_step, step], "device": str(self.device), "compile": bool(self.compile),
                "capture": bool(self.capture)}
        return self.segments + ([here] if step > self.first_step else [])

    def save(self, step: int, finished: bool = False) -> None:
        if self.checkpoint is not None:
            save_checkpoint(self.checkpoint, {
                "format": CHECKPOINT_FORMAT, "model": to_cpu(self.model.state_dict()),
                "optimizer": to_cpu(self.opt.state_dict()), "epoch": self.epoch, "batches_done": self.batch,
                "step": step, "meta": self.meta, "finished": finished, "frames": self.frames_before + self.frames,
                "seconds": self.seconds_before + time.perf_counter() - self.t0, "segments": self.trained_by(step)})

    def take_step(self, batch: dict, step: int) -> dict:
        self.frames += int(batch["mask"].sum())
        generator = step_generator(self.cfg.seed, step)
        if self.captured is not None:  # it copies the batch into its graph's inputs itself
            return self.captured(to_torch(batch), generator)
        loss, metrics = self.model.loss(to_device(to_torch(batch), self.device, non_blocking=True),
                                        generator=generator)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        metrics["grad_norm"] = float(torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.clip))
        self.opt.step()
        return metrics

    def after_step(self, step: int, metrics: dict, seconds: float) -> None:
        self.last = metrics
        if self.log_metrics is not None:
            self.log_metrics({"train": metrics, "epoch": self.epoch}, step)

    def window_batches(self):
        """Epochs of shuffled windows from the checkpoint's position, with a progress bar, a line and a checkpoint
        at each epoch's end; the step cap (max_steps) ends them mid-epoch."""
        from tqdm.auto import tqdm

        cfg, cap = self.cfg, self.cfg.max_steps
        step = self.first_step  # the steps taken: each batch is one, taken before the generator goes on
        started = None  # (clock, step) where this process started training: the pace is measured from there
        while self.epoch < cfg.epochs and (cap is None or step < cap):
            epoch = self.epoch
            batches = epoch_batches(self.dataset.windows(epoch), cfg.batch_size, cfg.seed, epoch)
            if not batches:
                raise UserError("no training windows: every training episode is shorter than the window length "
                                f"({self.dataset.spec.length}); use a shorter window (window.length) or pad_end")
            todo = batches[self.batch:]
            if cap is not None:
                todo = todo[: cap - step]
            if started is None:  # the plan, once: batches vary by a few per epoch with a random window offset
                started = (time.perf_counter(), step)
                planned = _planned_steps(cfg, epoch, self.batch, step, len(batches))
                log.info("training: about %d steps (%d epochs x ~%d batches of %d windows%s), from step %d", planned,
                         cfg.epochs, len(batches), cfg.batch_size, f", capped at {cap}" if cap is not None else "",
                         step)
            bar = tqdm(total=len(batches), initial=self.batch, desc=f"epoch {epoch + 1}/{cfg.epochs}",
                       disable=not self.progress, leave=False)
            for batch in _loader(self.dataset, todo, cfg.num_workers, pin_memory=self.device.type == "cuda"):
                self.batch += 1  # before its step: a checkpoint written after the step resumes past it
                yield batch
                step += 1
                bar.update(1)
                bar.set_postfix(loss=f"{self.last['loss']:.1f}")
            bar.close()
            if self.batch >= len(batches):
                self.epoch, self.batch = epoch + 1, 0
                _log_epoch(epoch + 1, cfg, step, self.last, started, len(batches))
            self.save(step)
        if cap is not None and step >= cap and self.epoch < cfg.epochs:
            where = (f"in epoch {self.epoch + 1}/{cfg.epochs}, after {self.batch} of its batches"
                     if self.batch else f"after epoch {self.epoch}/{cfg.epochs}")
            log.info("stopped at the step cap: step %d (max_steps), %s", step, where)


def _planned_steps(cfg: TrainConfig, epoch: int, done_in_epoch: int, step: int, batches_per_epoch: int) -> int:
    """Steps a run will have taken when it ends, from `step` with this epoch's batch count for every epoch left."""
    total = step + (cfg.epochs - epoch) * batches_per_epoch - done_in_epoch
    return total if cfg.max_steps is None else min(total, cfg.max_steps)


def _log_epoch(epoch: int, cfg: TrainConfig, step: int, last: dict, since: tuple[float, int], batches: int) -> None:
    """One line per finished epoch, so a run without progress bars (progress=false, SLURM logs) shows its pace and
    what is left. The pace is that of every step since `since` (clock, step), where this process started training:
    steadier than the last epoch's on a shared machine."""
    pace = (time.perf_counter() - since[0]) / max(step - since[1], 1)
    left = max(_planned_steps(cfg, epoch, 0, step, batches) - step, 0)
    log.info("epoch %d/%d done: step %d, loss %.1f, %.3f s/step, ~%s left", epoch, cfg.epochs, step,
             last.get("loss", float("nan")), pace, duration(left * pace))


@torch.no_grad()
def evaluate(model, dataset, seed: int = 0, batch_size: int = 16, context: int | None = None,
             per_task: bool = True, progress: bool = False) -> dict:
    """Errors over every evaluation window of `dataset` (its `windows(0)`), see the module docstring. `context`:
    observed frames before open-loop imagination (None: half the window). Runs where the model is."""
    from tqdm.auto import tqdm

    model.eval()
    device = module_device(model)
    windows = dataset.windows(0)
    if len(windows) == 0:
        raise UserError("no evaluation windows (episodes shorter than the window and no pad_end)")
    L = dataset.spec.length
    context = max(1, L // 2) if context is None else int(context)
    if not 1 <= context < L:
        raise UserError(f"eval.context={context}: expected 1 <= context < window length ({L})")
    gen = torch.Generator().manual_seed(int(seed))
    keys = ("image_se", "state_se", "kl_dyn", "kl_rep")
    tasks = [i.task for i in dataset.source.infos]
    sums: dict[str, dict[str, float]] = {}

    def add(task: str, key: str, v: float) -> None:
        sums.setdefault(task, {}).setdefault(key, 0.0)
        sums[task][key] += v

    batches = [[(int(e), int(s)) for e, s in windows[i : i + batch_size]] for i in range(0, len(windows), batch_size)]
    for batch in tqdm(_loader(dataset, batches, 0), total=len(batches), desc="eval", disable=not progress,
                      leave=False):
        b = to_torch(batch)  # stays on the CPU for the bookkeeping below
        on_device = to_device(b, device, non_blocking=True)
        # the errors come back in one copy per batch: the per-window sums below are CPU work, not GPU round trips
        e = to_cpu(model.step_errors(on_device, generator=gen))
        ol = to_cpu(model.open_loop_errors(on_device, context, generator=gen))
        mask = b["mask"].float()
        olmask = mask[:, context:]
        for j in range(mask.shape[0]):
            task = tasks[int(b["episode"][j, 0])]
            for name in ([task, "*"] if per_task else ["*"]):
                add(name, "frames", float(mask[j].sum()))
                add(name, "ol_frames", float(olmask[j].sum()))
                for k in keys:
                    add(name, k, float((e[k][j] * mask[j]).sum()))
                for k, v in ol.items():
                    add(name, "ol_" + k, float((v[j] * olmask[j]).sum()))
    pixels = model.cfg.image_size**2 * 3

    def summarise(s: dict) -> dict:
        n, m = max(s["frames"], 1.0), max(s["ol_frames"], 1.0)
        out = {"image_error": s["image_se"] / n, "image_error_per_pixel": s["image_se"] / n / pixels,
               "state_error": s["state_se"] / n, "kl_dyn": s["kl_dyn"] / n, "kl_rep": s["kl_rep"] / n,
               "open_loop_image_error": s["ol_image_se"] / m if s["ol_frames"] else None,
               "open_loop_image_error_per_pixel": s["ol_image_se"] / m / pixels if s["ol_frames"] else None,
               "frames": int(s["frames"]), "open_loop_frames": int(s["ol_frames"])}
        if "ol_state_se" in s:
            out["open_loop_state_error"] = s["ol_state_se"] / m if s["ol_frames"] else None
        return out

    result = summarise(sums.pop("*"))
    result.update(windows=int(len(windows)), context=context, horizon=L - context, seed=int(seed))
    if per_task:
        result["per_task"] = {t: summarise(s) for t, s in sorted(sums.items())}
    model.train()
    return result
