"""Preemption of a training loop at a step boundary, for jobs run by submitit (hydra/launcher=slurm,
submitit_slurm, submitit_local).

A preempted or timing-out job gets submitit's signal (USR2, or SUBMITIT_PREEMPT_SIGNAL). Submitit's handler
requeues the job and calls `sys.exit` from wherever the main thread happens to be. Two things go wrong with that
inside a training loop:
  - When the signal lands while Python runs a finaliser (a weakref callback, a `__del__`: tensors, HDF5 handles and
    progress bars have them), the SystemExit is printed as "Exception ignored in ..." and dropped. The job trains on
    as if nothing happened; under submitit's local executor it then exits 0 and is never requeued. (Seen here: a
    thread sending USR2 at random moments into world-model training lost exceptions this way.)
  - The steps since the last periodic checkpoint are lost.
So while a loop runs under `PreemptionPoint()`, the signal is only recorded. The loop checks `pending` after each
step, saves a checkpoint and calls `deliver()`, which runs submitit's own handler there: the requeue and the exit
then happen at a known place, with nothing lost.

Outside a submitit job (no SUBMITIT_EXECUTOR in the environment), off the main thread, or when no Python handler
is installed for the signal, nothing is changed. A step must end before the job's grace period does (submitit
signals 120 s before the time limit, conf/hydra/launcher/slurm.yaml); a step of the largest preset takes seconds.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType

log = logging.getLogger(__name__)


def preemption_signal() -> signal.Signals:
    """The signal submitit sends a preempted job: "SIG" + $SUBMITIT_PREEMPT_SIGNAL (default USR2), as submitit reads
    it (a name it does not know stops the job in submitit before any training starts)."""
    return getattr(signal, "SIG" + os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR2"), signal.SIGUSR2)


class PreemptionPoint:
    """Context manager; see the module docstring. `pending` is True once the signal came; `deliver()` hands it to
    the handler that was installed before (submitit's), which normally requeues the job and exits."""

    def __init__(self) -> None:
        self.pending = False
        self._signum: signal.Signals | None = None
        self._handler: Callable[[int, FrameType | None], object] | None = None

    def __enter__(self) -> PreemptionPoint:
        if not os.environ.get("SUBMITIT_EXECUTOR") or threading.current_thread() is not threading.main_thread():
            return self
        signum = preemption_signal()
        handler = signal.getsignal(signum)
        if callable(handler):
            self._signum, self._handler = signum, handler
            signal.signal(signum, self._record)
        return self

    def _record(self, signum: int, frame: FrameType | None) -> None:
        self.pending = True

    def _restore(self) -> Callable[[int, FrameType | None], object] | None:
        handler, self._handler = self._handler, None
        if handler is not None:
            signal.signal(self._signum, handler)
        return handler

    def deliver(self, step: int | None = None) -> None:
        """Run the previous handler for the recorded signal now (it may raise SystemExit: that is its job). Call it
        once the step's checkpoint is saved; `step` is logged."""
        if not self.pending:
            return
        if step is not None:
            log.info("preempted at step %d: checkpoint saved, handing over to submitit (requeue)", step)
        self.pending = False
        handler = self._restore()
        if handler is not None:
            handler(self._signum, None)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None and self.pending:
            self.deliver()  # came during the loop's last step: the caller's final checkpoint is written by now
        self._restore()
