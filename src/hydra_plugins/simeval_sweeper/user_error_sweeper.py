"""Hydra's basic sweeper, plus one thing: when a job of the sweep stopped on a user error (simeval.errors.UserError)
in a process of its own (the submitit launchers: `submitit_local`, `slurm`), the launching process prints its one
`error: ...` line and exits 2, as every other path does, instead of Hydra's traceback of the failed job; a job that
died without a result (killed, out of memory) ends it with one line naming the job's log and exit 1, and so does
a job submitit did not requeue again (its time limit reached more often than max_num_timeout allows); and a job
that raised any other exception ends it, after the others have run, with one line per failed job naming its log.
Selected in conf/hydra/default.yaml (`sweeper._target_`); the logic is simeval.cli.stop_sweep_on_user_errors."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.utils import JobReturn


class _StopOnUserErrors:
    """The sweep's launcher, whose job results are checked for user errors before the sweeper reads them."""

    def __init__(self, launcher: Any) -> None:
        self.launcher = launcher

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from simeval.cli import (stop_sweep_on_dead_jobs, stop_sweep_on_failed_jobs, stop_sweep_on_unrequeued_jobs,
                                 stop_sweep_on_user_errors)

        results = stop_sweep_on_dead_jobs(lambda: self.launcher.launch(job_overrides, initial_job_idx=initial_job_idx))
        stop_sweep_on_user_errors(results)
        stop_sweep_on_unrequeued_jobs(results, dict(getattr(self.launcher, "params", None) or {}))
        stop_sweep_on_failed_jobs(results)
        return results


class UserErrorSweeper(BasicSweeper):
    def setup(self, **kwargs: Any) -> None:
        super().setup(**kwargs)
        self.launcher = _StopOnUserErrors(self.launcher)
