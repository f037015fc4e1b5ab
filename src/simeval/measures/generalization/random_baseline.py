"""The chance baseline of Table 5: uniform random actions, rolled out on the same splits, tasks, seeds and step
limits as a trained policy (`policy=random` in src/generalization.py: no data, no training).

Per rollout with seed s, action t ~ Uniform(low, high) of the environment's action space (a Box), drawn from
numpy's generator seeded with (s, 23): the same seed gives the same actions. A success of this actor is what a
group's task lets happen by chance (a button pressed by a random swing, a drawer pushed shut), so a policy's rate
reads against it.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


class RandomActions:
    """A policy stand-in for simeval.measures.generalization.rollouts.rollout_task: `cfg` carries what the rollout and
    its cache key read (action space, cameras, frame size, sampler), `runner(env)` the per-rollout actor."""

    def __init__(self, action_space: str, cameras=("top",), image_size=(64, 64)) -> None:
        self.cfg = SimpleNamespace(action_space=action_space, cameras=list(cameras), image_size=list(image_size),
                                   inference_scheduler="uniform-random", num_inference_steps=0)

    def runner(self, env) -> "_RandomRunner":
        return _RandomRunner(env.action_space)


class _RandomRunner:
    def __init__(self, space) -> None:
        self.low, self.high = np.asarray(space.low, np.float64), np.asarray(space.high, np.float64)
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng([int(seed or 0), 23])

    def act(self, obs) -> np.ndarray:
        return self.rng.uniform(self.low, self.high).astype(np.float32)
