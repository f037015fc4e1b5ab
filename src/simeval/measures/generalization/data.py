"""Training windows for the Diffusion Policy, held in memory (a task group at 64x64 is a few hundred MB at most).

    PolicyDataset(episodes, ...): per episode the observation before each action (image per camera, state) and the
        action. `action_space` joint, ee_delta, ee_pose or metaworld (Meta-World's own 4-d action): every control
        step (the stored episode must have been recorded in that action space); `"pick_place"`: one step per primitive (the 14-d
        pose and the observation where the primitive starts, `high_level_step`).
    sample(batch_size, generator) -> {"rgb": {cam: (B, To, H, W, 3) uint8}, "state": (B, To, S), "action": (B, Tp, A)}

Windows follow the official SequenceSampler: a window of Tp = horizon steps starting at s, indices clipped to the
episode (so the first observation and the last action repeat at the edges). Starts run over [-(To-1), T-To], so
every action of an episode is the first executed action of some window; the official sampler stops Ta-1 steps
earlier, which for a horizon-2 pick/place policy would never train the last primitive as the executed one.

Episodes are in the store's format 2 (simeval.episodes.store): T actions, T + 1 observation rows; the pairs are
(row t, action t) for t < T (row T, the final observation, has padding for an action and is left out), and a
pick/place step pairs the observation at the row where the primitive was chosen with its 14-d pose. This is a small
in-memory reader of its own rather than simeval.episodes.dataset (the world model's lazy window dataset): the
official Diffusion Policy sampler clips windows to the episode instead of padding and masking them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch.nn import functional as F

from simeval.episodes.episode import Episode
from simeval.errors import UserError

LOW_LEVEL = ("joint", "ee_delta", "ee_pose", "metaworld", "recorded")  # one stored action per control step
RECORDED = "recorded"  # the episodes' own kind, whatever it is (a Gymnasium pipeline's): PolicyDataset checks one
ACTION_SPACES = (*LOW_LEVEL, "pick_place")


def _resize(frames: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if tuple(frames.shape[1:3]) == tuple(size):
        return frames
    x = torch.from_numpy(frames).permute(0, 3, 1, 2).float()
    x = F.interpolate(x, size=tuple(size), mode="bilinear", antialias=True, align_corners=False)
    return x.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def episode_steps(ep: Episode, action_space: str, cameras: Sequence[str]) -> tuple[dict, np.ndarray, np.ndarray]:
    """(rgb {cam: (N, H, W, 3)}, state (N, S), action (N, A)): the observation before each of the N actions."""
    if action_space not in ACTION_SPACES:
        raise UserError(f"policy.model.action_space={action_space!r}: expected one of {', '.join(ACTION_SPACES)}")
    missing = [c for c in cameras if c not in ep.rgb]
    if missing:
        raise UserError(f"{ep.task} seed {ep.seed}: no camera {missing} in the stored episode (has {sorted(ep.rgb)});"
                        f" set policy.model.cameras to stored ones or collect with record.cameras including them")
    if action_space in LOW_LEVEL:
        # the store's rows 0..T-1 with the action taken after each (row T, the final observation, has padding)
        from simeval.pipelines.metaworld.native import ACTION_KIND as METAWORLD_KIND
        from simeval.sim.env import ACTION_SPACES as SUITE_KINDS

        KINDS = {**SUITE_KINDS, "metaworld": METAWORLD_KIND}

        stored = (ep.action_space or {}).get("kind")  # None: an episode built in memory, not read from a store
        if stored is not None and action_space != RECORDED and stored != KINDS[action_space]:
            native = {kind: name for name, kind in KINDS.items()}.get(stored, stored)
            raise UserError(f"{ep.task} seed {ep.seed}: its actions were recorded as {stored!r}, the policy's "
                            f"action_space={action_space} needs {KINDS[action_space]!r}; set policy.model."
                            f"action_space=native (the tasks' own: {native})")
        idx = np.arange(ep.n_actions)
        action = np.asarray(ep.action, np.float32)[: ep.n_actions]
    else:
        if ep.high_level_action is None or len(ep.high_level_action) == 0:
            raise UserError(f"{ep.task} seed {ep.seed}: no high-level (pick/place) actions stored; "
                            f"policy.model.action_space=pick_place needs them")
        idx = np.minimum(np.asarray(ep.high_level_step, np.int64), len(ep.state) - 1)
        action = np.asarray(ep.high_level_action, np.float32)
    return {c: ep.rgb[c][idx] for c in cameras}, np.asarray(ep.state, np.float32)[idx], action


class PolicyDataset:
    def __init__(self, episodes: Sequence[Episode], action_space: str, cameras: Sequence[str],
                 image_size: Sequence[int], horizon: int, n_obs_steps: int) -> None:
        if not episodes:
            raise UserError("no training episodes: the task group has none in the store (run src/collect.py first)")
        self.cameras, self.horizon, self.n_obs_steps = tuple(cameras), int(horizon), int(n_obs_steps)
        kinds = {(ep.action_space or {}).get("kind") for ep in episodes} - {None}
        if action_space == RECORDED and len(kinds) > 1:
            raise UserError(f"policy.model.action_space={RECORDED}: the training episodes were recorded in "
                            f"{len(kinds)} action spaces ({', '.join(sorted(kinds))}); one policy acts in one")
        rgb = {c: [] for c in self.cameras}
        states, actions, lengths = [], [], []
        for ep in episodes:
            r, s, a = episode_steps(ep, action_space, self.cameras)
            for c in self.cameras:
                rgb[c].append(_resize(r[c], tuple(image_size)))
            states.append(s)
            actions.append(a)
            lengths.append(len(a))
        dims = {a.shape[1] for a in actions}
        if len(dims) != 1 or len({s.shape[1] for s in states}) != 1:
            raise UserError(f"episodes disagree on action/state sizes {sorted(dims)}: one training set cannot mix "
                            f"action spaces or robots")
        self._index({c: torch.from_numpy(np.concatenate(v)) for c, v in rgb.items()},
                    torch.from_numpy(np.concatenate(states)), torch.from_numpy(np.concatenate(actions)), lengths)

    @classmethod
    def from_arrays(cls, rgb: dict, state: torch.Tensor, action: torch.Tensor, lengths, horizon: int,
                    n_obs_steps: int) -> PolicyDataset:
        """The dataset of steps already extracted (`arrays()` of another one): trains where the store is not, e.g.
        on a GPU machine the episodes were not copied to (simeval.measures.generalization.offline)."""
        self = cls.__new__(cls)
        self.cameras, self.horizon, self.n_obs_steps = tuple(rgb), int(horizon), int(n_obs_steps)
        self._index(dict(rgb), state, action, lengths)
        return self

    def arrays(self) -> dict:
        return {"rgb": self.rgb, "state": self.state, "action": self.action, "lengths": self.lengths.tolist()}

    def _index(self, rgb: dict, state: torch.Tensor, action: torch.Tensor, lengths) -> None:
        self.rgb, self.state, self.action = rgb, state, action
        self.lengths = np.asarray(lengths)
        self.offsets = np.r_[0, np.cumsum(self.lengths)[:-1]]
        # every (episode, start) with start in [-(To-1), T-To]: T windows per episode of T actions
        self.starts = np.concatenate([np.stack([np.full(n, e), np.arange(n) - (self.n_obs_steps - 1)], 1)
                                      for e, n in enumerate(self.lengths)])
        self.state_dim, self.action_dim = self.state.shape[1], self.action.shape[1]

    def __len__(self) -> int:
        return len(self.starts)

    def window(self, rows: np.ndarray) -> dict:
        """The windows of `rows` (indices into self.starts)."""
        ep, start = self.starts[rows, 0], self.starts[rows, 1]
        steps = start[:, None] + np.arange(self.horizon)[None]
        steps = np.clip(steps, 0, self.lengths[ep][:, None] - 1) + self.offsets[ep][:, None]
        idx = torch.from_numpy(steps)
        obs_idx = idx[:, : self.n_obs_steps]
        return {"rgb": {c: v[obs_idx] for c, v in self.rgb.items()}, "state": self.state[obs_idx],
                "action": self.action[idx]}

    def sample(self, batch_size: int, generator: torch.Generator) -> dict:
        rows = torch.randint(0, len(self), (batch_size,), generator=generator).numpy()
        return self.window(rows)

    def stats(self) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """Per-dimension (min, max) of state and action: what the normaliser maps to [-1, 1]."""
        return {"state": (self.state.min(0).values, self.state.max(0).values),
                "action": (self.action.min(0).values, self.action.max(0).values)}
