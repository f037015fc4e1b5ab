"""Run loggers, chosen by the `logger` config group: none, csv, wandb. All are context managers so that
`finish()` runs even when the run fails."""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from simeval.results import redact_secrets


def _flatten(d: Mapping, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{key}/"))
        elif isinstance(v, (int, float, str, bool)) or v is None:
            out[key] = v
    return out


class NullLogger:
    def __init__(self, **_: Any) -> None:
        pass

    def log_metrics(self, metrics: Mapping, step: int | None = None) -> None:
        pass

    def finish(self, exit_code: int = 0) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.finish(exit_code=0 if exc_type is None else 1)


class CsvLogger(NullLogger):
    """Appends one row per `log_metrics` call to `<run_dir>/metrics.csv` (long format: step, key, value)."""

    def __init__(self, run_dir: str, filename: str = "metrics.csv", **_: Any) -> None:
        self.path = Path(run_dir) / filename
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def log_metrics(self, metrics: Mapping, step: int | None = None) -> None:
        new = not self.path.exists()
        with self.path.open("a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["step", "key", "value"])
            for k, v in _flatten(metrics).items():
                w.writerow([step, k, v])


class WandbLogger(NullLogger):
    """Weights & Biases, offline unless `mode=online`. The config is redacted of secrets before upload."""

    def __init__(
        self,
        run_dir: str,
        project: str = "simeval",
        entity: str | None = None,
        mode: str = "offline",
        name: str | None = None,
        group: str | None = None,
        tags: list[str] | None = None,
        run_config: Mapping | None = None,
        **_: Any,
    ) -> None:
        if mode not in ("offline", "online", "disabled"):
            raise ValueError(f"logger.mode={mode!r}: expected one of offline, online, disabled")
        import wandb  # lazy: importing wandb costs ~1 s

        os.environ.setdefault("WANDB_SILENT", "true")
        self.run = wandb.init(
            project=project, entity=entity, mode=mode, name=name, group=group, tags=list(tags or []),
            dir=str(run_dir), config=redact_secrets(dict(run_config or {})), reinit="finish_previous",
        )

    def log_metrics(self, metrics: Mapping, step: int | None = None) -> None:
        # None is "undefined" (e.g. Pearson of a constant column): left out rather than charted as a value
        self.run.log({k: v for k, v in _flatten(metrics).items() if v is not None}, step=step)

    def finish(self, exit_code: int = 0) -> None:
        if self.run is not None:
            self.run.finish(exit_code=exit_code)
            self.run = None
