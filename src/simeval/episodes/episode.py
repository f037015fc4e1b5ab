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
    # per-step arrays have T + 1 rows for T actions (the convention in store.py: row 0 is the reset observation,
    # action t produced row t + 1, the last row's action is padding)
    rgb: dict[str, np.ndarray]  # camera -> (T+1, H, W, 3) uint8
    state: np.ndarray  # (T+1, D)
    action: np.ndarray  # (T+1, A)
    reward: np.ndarray  # (T+1,)
    is_first: np.ndarray  # (T+1,)
    is_terminal: np.ndarray  # (T+1,)
    progress: np.ndarray | None = None  # (T+1,); None when the source does not record it
    success: bool = False
    success_known: bool = True  # False for sources that do not record success (the authors' GenSim/RoboGen files)
    high_level_action: np.ndarray | None = None  # (H, K)
    high_level_step: np.ndarray | None = None  # (H,)
    scene_views: np.ndarray | None = None  # (V, h, w, 3)
    final_view: np.ndarray | None = None  # (h, w, 3) the first scene view rendered after the episode (optional)
    control_hz: float | None = None
    source: str = "simeval"
    extra: dict = field(default_factory=dict)
    action_space: dict | None = None  # {kind, dims, units, control_hz, ...}; see simeval.sim.env
    high_level_space: dict | None = None  # the space of high_level_action (pick_place_14d)
    state_names: list[str] | None = None  # (D,) names of the state dimensions
    variation: dict | None = None  # the knobs this episode's instance was varied with ({} or None: none)
    depth: dict[str, np.ndarray] | None = None  # camera -> (T+1, H, W) float32 metres (optional)
    object_poses: np.ndarray | None = None  # (T+1, N, 7) (optional)
    language: list[str] | None = None  # (T+1,) per-step language goals (optional)
    robot_mask: dict[str, np.ndarray] | None = None  # camera -> (T+1, H, W) bool: the robot's pixels (optional)

    @property
    def n_steps(self) -> int:
        """Rows: T + 1 observations (the last row's action is padding)."""
        return int(len(self.action))

    @property
    def n_actions(self) -> int:
        return max(0, self.n_steps - 1)

    def validate(self) -> None:
        t = self.n_steps
        arrays = {"state": self.state, "reward": self.reward, "is_first": self.is_first,
                  "is_terminal": self.is_terminal, **{f"rgb/{k}": v for k, v in self.rgb.items()}}
        if self.progress is not None:
            arrays["progress"] = self.progress
        arrays.update({f"depth/{k}": v for k, v in (self.depth or {}).items()})
        arrays.update({f"robot_mask/{k}": v for k, v in (self.robot_mask or {}).items()})
        if self.object_poses is not None:
            arrays["object_poses"] = self.object_poses
        if self.language is not None:
            arrays["language"] = self.language
        bad = {k: len(v) for k, v in arrays.items() if len(v) != t}
        if bad:
            raise EpisodeFormatError(f"{self.task} seed {self.seed}: {t} rows of actions but lengths {bad}")
        if t < 2:
            raise EpisodeFormatError(f"{self.task} seed {self.seed}: an episode has at least 2 rows (the reset "
                                     f"observation and one after an action), got {t}")
        if self.action_space is None or not self.action_space.get("kind"):
            raise EpisodeFormatError(f"{self.task} seed {self.seed}: action_space (with a kind) is required")
        for cam, frames in self.rgb.items():
            if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
                raise EpisodeFormatError(f"camera {cam}: expected uint8 (T, H, W, 3), got {frames.dtype} {frames.shape}")
        if (self.high_level_action is None) != (self.high_level_step is None):
            raise EpisodeFormatError("high_level_action and high_level_step go together")
