"""What both models' training loops share (the world model's, simeval.models.training.train; the policy's,
simeval.models.diffusion_policy.train_policy): the resume check and the checkpoint cadence with preemption.

    refuse_other_settings(path, stored, current, where)   # a checkpoint made with other settings: UserError naming
                                                          # the keys that differ
    with CheckpointedSteps(save, every) as loop:          # save() writes the model's own checkpoint
        for ...:
            <one training step>
            loop.step_done(step)                          # checkpoint every `every` steps and at a preemption
        save()                                            # the loop's final checkpoint, the model's own

What one step is (a window batch of an epoch; a sampled batch with an LR schedule and an EMA) and what a checkpoint
holds stay with each model: their files differ (simeval.models.checkpoints reads and writes both).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from typing import Self

from simeval.errors import UserError
from simeval.models.preemption import PreemptionPoint


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
    (simeval.models.preemption): a killed run loses at most `every` steps, a preempted one none. A signal that came
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
