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

Submitit's SLURM handler requeues with a child process, `scontrol requeue <job>`, and SLURM carries out a requeue
by sending SIGTERM to every process of the job: the `scontrol` child too, which can get it before it exits. Submitit
only ignores SIGTERM in the job's own process (a Python handler, reset to the default in a child), so the child dies
of it, `check_call` raises CalledProcessError out of the handler, the job ends with that error as its result and the
sweep fails although the job was requeued. (Seen: a CI run's preemption test, "Command '['scontrol', 'requeue',
'11']' died with <Signals.SIGTERM: 15>".) `deliver()` therefore ignores SIGTERM (SIG_IGN, which a child inherits)
while the handler runs, and puts the previous SIGTERM handler back after it; `requeue_deaf_to_sigterm()`, called
at the start of every entrypoint's job (simeval.cli.exit_cleanly_on_user_error), does the same for a signal that
comes outside a training loop (loading data, evaluating), where submitit's handler runs at once.

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
            _run_deaf_to_sigterm(handler, self._signum)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None and self.pending:
            self.deliver()  # came during the loop's last step: the caller's final checkpoint is written by now
        self._restore()


def _run_deaf_to_sigterm(handler: Callable[[int, FrameType | None], object], signum: int,
                         frame: FrameType | None = None) -> None:
    """Run `handler(signum, frame)` with SIGTERM ignored, so the processes it starts (`scontrol requeue`) outlive the
    SIGTERM the requeue sends the whole job; see the module docstring. A SIGTERM handler not installed from Python
    (getsignal gives None) could not be put back, so it is then left as it is."""
    if signal.getsignal(signal.SIGTERM) is None:
        handler(signum, frame)
        return
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        handler(signum, frame)
    finally:
        signal.signal(signal.SIGTERM, previous)


def requeue_deaf_to_sigterm() -> None:
    """In a submitit job's main thread, replace submitit's handler for its preemption signal with one that runs it
    deaf to SIGTERM (see the module docstring). Outside a job, off the main thread, with no Python handler on the
    signal, or when already done, nothing changes."""
    if not os.environ.get("SUBMITIT_EXECUTOR") or threading.current_thread() is not threading.main_thread():
        return
    signum = preemption_signal()
    handler = signal.getsignal(signum)
    if not callable(handler) or getattr(handler, "deaf_to_sigterm", False):
        return

    def deaf_handler(received: int, frame: FrameType | None) -> None:
        _run_deaf_to_sigterm(handler, received, frame)

    deaf_handler.deaf_to_sigterm = True  # type: ignore[attr-defined]
    signal.signal(signum, deaf_handler)
