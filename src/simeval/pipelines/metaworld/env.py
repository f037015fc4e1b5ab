"""Meta-World's own task as a Gymnasium environment observed the way simeval's are, for closed-loop evaluation.

    MetaworldEnv(task, settings, image_size, cameras, max_steps)
    reset(seed) -> obs, info     variant `seed` of the task (Meta-World's own seeding; one MuJoCo model per seed)
    step(action (4,)) -> obs, reward, terminated, truncated, info
    obs: {"rgb": {camera: (H, W, 3) uint8}, "state": (39,) float32 (Meta-World's observation)}
    info: {"success": Meta-World's success, "progress": its shaped reward / 10}; terminated on success, truncated
    after `max_steps` actions. reward = the change of progress, as in the store (simeval.episodes.store).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import ClassVar

import gymnasium as gym
import numpy as np

from simeval.errors import UserError
from simeval.pipelines.metaworld.native import (
    CAMERAS,
    STATE_NAMES,
    Cameras,
    MetaworldSettings,
    make_task_env,
    progress_of,
)


class MetaworldEnv(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, task: str, settings: MetaworldSettings, image_size: Sequence[int], cameras: Sequence[str],
                 max_steps: int | None = None) -> None:
        self.task, self.cameras, self.image_size = task, list(cameras), tuple(int(x) for x in image_size)
        self.settings = settings if max_steps is None else replace(settings, max_steps=int(max_steps))
        self.action_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
        self.observation_space = gym.spaces.Dict({
            "rgb": gym.spaces.Dict({c: gym.spaces.Box(0, 255, (*self.image_size, 3), np.uint8) for c in cameras}),
            "state": gym.spaces.Box(-np.inf, np.inf, (len(STATE_NAMES),), np.float32)})
        unknown = [c for c in cameras if c not in CAMERAS]
        if unknown:
            raise UserError(f"policy.model.cameras: Meta-World's environment has cameras {list(CAMERAS)}, not "
                            f"{unknown}")
        self._env = self._cams = None

    def _observe(self, obs: np.ndarray) -> dict:
        rgb, _ = self._cams.render(with_masks=False)
        return {"rgb": rgb, "state": obs.astype(np.float32)}

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        self.close()
        self._env, obs = make_task_env(self.task, 0 if seed is None else int(seed), self.settings.hand_init_noise)
        self._cams = Cameras(self._env, self.cameras, self.image_size, self.settings.render_quality)
        self._steps, self._progress = 0, progress_of(self._env, obs)
        return self._observe(obs), {"success": False, "progress": self._progress}

    def step(self, action):
        action = np.clip(np.asarray(action, np.float32).reshape(4), -1.0, 1.0)
        obs, reward, _, _, info = self._env.step(action)
        self._steps += 1
        progress = float(np.clip(reward / 10.0, 0.0, 1.0))
        delta, self._progress = progress - self._progress, progress
        success = bool(info["success"])
        return (self._observe(obs), delta, success, self._steps >= self.settings.max_steps and not success,
                {"success": success, "progress": progress})

    def close(self) -> None:
        if self._cams is not None:
            self._cams.close()
        if self._env is not None:
            self._env.close()
        self._env = self._cams = None
