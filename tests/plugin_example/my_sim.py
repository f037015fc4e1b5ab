"""A user's own simulator: a point that moves toward a target on a plane, rendered as two disks."""
import gymnasium as gym
import numpy as np

from simeval.pipelines.gymnasium.pipeline import GymnasiumPipeline


class PointReach(gym.Env):
    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, target=(0.5, 0.0), gain=0.05, size=48, render_mode=None):
        self.target, self.gain, self.size, self.render_mode = np.asarray(target, np.float32), gain, size, render_mode
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = gym.spaces.Dict({"pos": gym.spaces.Box(-1, 1, (2,), np.float32),
                                                  "target": gym.spaces.Box(-1, 1, (2,), np.float32)})

    def _obs(self):
        return {"pos": self.pos.copy(), "target": self.target.copy()}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = self.target
        while np.linalg.norm(self.pos - self.target) < 0.6:  # start away from the target: episodes of 12+ steps
            self.pos = self.np_random.uniform(-0.9, 0.9, 2).astype(np.float32)
        return self._obs(), {"is_success": False}

    def step(self, action):
        self.pos = np.clip(self.pos + self.gain * np.asarray(action, np.float32), -1, 1)
        done = bool(np.linalg.norm(self.pos - self.target) < 0.1)
        return self._obs(), float(done), done, False, {"is_success": done}

    def render(self):
        img = np.full((self.size, self.size, 3), 90, np.uint8)
        yy, xx = np.mgrid[: self.size, : self.size]
        for p, colour in ((self.target, (40, 200, 40)), (self.pos, (220, 50, 40))):
            cx, cy = (p + 1) / 2 * (self.size - 1)
            img[(xx - cx) ** 2 + (yy - cy) ** 2 <= (self.size * 0.06) ** 2] = colour
        return img


gym.register("PointReach-v0", entry_point="my_sim:PointReach")


def expert(env, obs, info, rng):
    step = obs["target"] - obs["pos"]
    return np.clip(step / max(np.linalg.norm(step), 1e-6) + rng.normal(0, 0.2, 2), -1, 1)


class MyPipeline(GymnasiumPipeline):
    """A plugin: simeval finds it through the yaml's _target_."""
