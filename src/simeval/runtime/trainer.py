"""The one training loop of both models (the world model's, simeval.models.world_model_training.train; the policy's,
simeval.models.diffusion_policy.train_policy), with its resume check and its checkpoint cadence with preemption.

    refuse_other_settings(path, stored, current, where)   # a checkpoint made with other settings: UserError naming
                                                          # the keys that differ
    step = run_steps(batches, take_step, save, step=resumed_at, checkpoint_every=N, after_step=..., final_save=...)
        for each batch: take_step(batch, i) -> metrics   # one gradient step, the model's own (i: steps before)
                        after_step(step, metrics, s)     # progress, logging (s: seconds of the fetch and the step)
                        checkpoint every N steps and at a preemption (CheckpointedSteps), then the signal goes on
        after the last batch: final_save()               # or save()

What a model owns is passed in: where its batches come from and in which order (epochs of windows for the world
model, batches sampled from a generator for the policy; each resumes from the checkpoint's position, so a resumed
run draws what an uninterrupted one would have), what one step is (Adam and a clip; AdamW, an LR schedule and an
EMA) and what a checkpoint holds (their files differ: simeval.runtime.checkpoints reads and writes both).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Self

from simeval.errors import UserError
from simeval.runtime.preemption import PreemptionPoint


def duration(seconds: float) -> str:
    """A time left as a log line says it: seconds under 90 s, minutes above."""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def settings_difference(stored: Mapping, current: Mapping) -> list[str]:
    """The keys whose values differ between two settings mappings (a key missing on one side differs), sorted;
    nested mappings by their dotted keys."""
    keys = []
    for k in sorted(set(stored) | set(current), key=str):
        a, b = stored.get(k), current.get(k)
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            keys += [f"{k}.{sub}" for sub in settings_difference(a, b)]
        elif a != b:
            keys.append(str(k))
    return keys


def refuse_other_settings(path: str | os.PathLike, stored: Mapping, current: Mapping, where: str) -> None:
    """A checkpoint found where a run would resume, made with other settings or data: one UserError naming the
    keys that differ (resuming would train a mix of two runs). `where`: what the user can change instead (the
    run folder, checkpoint_dir)."""
    diff = settings_difference(stored, current)
    if diff:
        raise UserError(f"{path}: made with other settings or data ({', '.join(diff)}); delete it or use another "
                        f"{where}")


class CheckpointedSteps:
    """Context manager for a training loop: `step_done(step)` after each step writes a checkpoint (`save()`) every
    `every` steps (where `periodic`) and whenever a preemption signal came, then hands that signal over to submitit
    (simeval.runtime.preemption): a killed run loses at most `every` steps, a preempted one none. A signal that came
    during the last step is delivered on leaving, after the loop's final save()."""

    def __init__(self, save: Callable[[], None], every: int) -> None:
        self.save, self.every = save, every
        self._preemption = PreemptionPoint()

    def __enter__(self) -> Self:
        self._preemption.__enter__()
        return self

    def step_done(self, step: int, periodic: bool = True) -> None:
        """After step `step` (1-based count of steps taken). periodic=False: no periodic checkpoint here (the policy
        writes its last one once, after the loop)."""
        if (periodic and step % self.every == 0) or self._preemption.pending:
            self.save()
        self._preemption.deliver(step)  # only when the signal came: after the checkpoint above

    def __exit__(self, exc_type, exc, tb) -> None:
        self._preemption.__exit__(exc_type, exc, tb)


def run_steps(batches: Iterable[Any], take_step: Callable[[Any, int], dict], save: Callable[[int], None], *, step: int,
              checkpoint_every: int, last_step: int | None = None,
              after_step: Callable[[int, dict, float], None] | None = None,
              final_save: Callable[[int], None] | None = None) -> int:
    """Take one step per batch, take_step(batch, steps taken before it), counting from `step` (where a resumed run
    starts); after each, after_step(step, metrics, seconds) and the checkpoint cadence: save(step) every
    `checkpoint_every` steps, not at `last_step` (where the final save follows at once), and whenever a preemption
    signal came. After the last batch, final_save(step) (default save). Returns the step count at the end."""
    with CheckpointedSteps(lambda: save(step), checkpoint_every) as loop:
        it = iter(batches)
        while True:
            t0 = time.perf_counter()
            batch = next(it, _DONE)
            if batch is _DONE:
                break
            metrics = take_step(batch, step)
            step += 1
            if after_step is not None:
                after_step(step, metrics, time.perf_counter() - t0)
            loop.step_done(step, periodic=last_step is None or step < last_step)
        (final_save or save)(step)
    return step


_DONE = object()  # the end of the batches (a batch may be anything, None included)
