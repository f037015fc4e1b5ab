"""One episode in memory, whatever its source (simeval's simulator, an importer) and wherever it goes (the
store, bundles for judges). The on-disk format lives in store.py; this module has no I/O, so the simulator can
build episodes without importing the storage layer."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simeval.errors import UserError


class EpisodeFormatError(UserError):
    """An episode file is missing, truncated, incomplete or not in this format; the message names the file."""


@dataclass
class Episode:
    pipeline: str
    task: str
    description: str
    group: str
    seed: int
    rgb: dict[str, np.ndarray]  # camera -> (T, H, W, 3) uint8
    state: np.ndarray  # (T, D)
    action: np.ndarray  # (T, A)
    reward: np.ndarray  # (T,)
    is_first: np.ndarray  # (T,)
    is_terminal: np.ndarray  # (T,)
    progress: np.ndarray | None = None  # (T,); None when the source does not record it
    success: bool = False
    success_known: bool = True  # False for sources that do not record success (the authors' GenSim/RoboGen files)
    high_level_action: np.ndarray | None = None  # (H, K)
    high_level_step: np.ndarray | None = None  # (H,)
    scene_views: np.ndarray | None = None  # (V, h, w, 3)
    final_view: np.ndarray | None = None  # (h, w, 3) the first scene view rendered after the episode (optional)
    control_hz: float | None = None
    source: str = "simeval"
    extra: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        return int(len(self.action))

    def validate(self) -> None:
        t = self.n_steps
        arrays = {"state": self.state, "reward": self.reward, "is_first": self.is_first,
                  "is_terminal": self.is_terminal, **{f"rgb/{k}": v for k, v in self.rgb.items()}}
        if self.progress is not None:
            arrays["progress"] = self.progress
        bad = {k: len(v) for k, v in arrays.items() if len(v) != t}
        if bad:
            raise EpisodeFormatError(f"{self.task} seed {self.seed}: {t} actions but lengths {bad}")
        for cam, frames in self.rgb.items():
            if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
                raise EpisodeFormatError(f"camera {cam}: expected uint8 (T, H, W, 3), got {frames.dtype} {frames.shape}")
        if (self.high_level_action is None) != (self.high_level_step is None):
            raise EpisodeFormatError("high_level_action and high_level_step go together")
