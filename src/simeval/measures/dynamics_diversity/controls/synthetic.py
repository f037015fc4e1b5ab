"""A validity control for dynamics diversity, where the answer is known: groups of synthetic tasks that share one
dynamics against groups whose tasks each have their own.

Every task renders one coloured square on a grey background (a distinct colour per task, in both kinds of group,
so the groups look alike at reset) and starts from the same distribution: a uniform position in [0.2, 0.8]^2, side
0.3, brightness 1. State (4,): x, y, side, brightness. Action (2,): a smooth random walk in [-1, 1]^2. What the
action does is the task's dynamics:
    move      position += 0.12 a                       (the only dynamics of a "shared" group)
    turn      position += 0.12 R(90 deg) a             (the action rotated)
    scale     side += 0.06 a_0, position += 0.04 a_1   (the square grows and shrinks)
    fade      brightness += 0.15 a_0, position += 0.04 a_1
    orbit     position rotates about the centre by 0.25 a_0 radians, radius += 0.03 a_1
    drift     position += 0.12 a mirrored in x, then a constant pull of 0.02 downwards
A "diverse" group of k tasks takes the first k dynamics in DYNAMICS order, a "shared" group k times `move`. A
dynamics-diversity metric must give the diverse group the larger error at few episodes and the larger drop as
episodes grow. The one-off script that ran these groups under the paper protocol is deleted (its answer,
outputs/tables/world_model_control.json, is committed; the script: `git show
647de4d:experiments/world_model_control.py`); the groups remain the world model's test and benchmark data.

Dynamics only (`make_physics_group`): the visuals are identical across tasks and groups (one colour, one size, the
same background: only the position of the square shows), and only the physics differs. State (4,): x, y, vx, vy.
The action a (2,) is a push: per control step
    v <- (1 - friction) v + gain R(turn) a        (mass: 1 / gain; push response: the push direction turned)
    p <- p + v; at a wall of [0.15, 0.85]^2 the square is reflected and that velocity component becomes -e v
                                                  (e: restitution)
A "shared" group gives every task PHYSICS[0]; a "varied" group gives task i PHYSICS[i].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from simeval.episodes.dataset import ArraySource, EpisodeInfo

DYNAMICS = ("move", "turn", "scale", "fade", "orbit", "drift")
COLORS = np.array([[230, 60, 60], [60, 200, 80], [70, 110, 240], [240, 200, 50], [200, 80, 220], [60, 210, 220]],
                  np.float32)
ACTION_SPACE = {"kind": "synthetic_2d", "dims": ["a0", "a1"], "units": ["1", "1"]}


def _render(state: np.ndarray, color: np.ndarray, size: int) -> np.ndarray:
    """(n, 4) states -> (n, size, size, 3) uint8, the square antialiased by pixel coverage."""
    n = len(state)
    grid = (np.arange(size, dtype=np.float32) + 0.5) / size
    x, y, side, bright = (state[:, i][:, None] for i in range(4))
    half = side / 2
    cover_x = np.clip(np.minimum(grid[None] + 0.5 / size, x + half) - np.maximum(grid[None] - 0.5 / size, x - half),
                      0, 1 / size) * size
    cover_y = np.clip(np.minimum(grid[None] + 0.5 / size, y + half) - np.maximum(grid[None] - 0.5 / size, y - half),
                      0, 1 / size) * size
    alpha = cover_y[:, :, None] * cover_x[:, None, :]  # (n, H, W)
    bg = np.full(3, 90.0, np.float32)
    fg = np.clip(color[None] * bright, 0, 255)  # (n, 3)
    img = bg[None, None, None] * (1 - alpha[..., None]) + fg[:, None, None, :] * alpha[..., None]
    return np.clip(np.round(img), 0, 255).astype(np.uint8).reshape(n, size, size, 3)


def _step(dyn: str, s: np.ndarray, a: np.ndarray) -> np.ndarray:
    x, y, side, bright = s
    if dyn == "move":
        x, y = x + 0.12 * a[0], y + 0.12 * a[1]
    elif dyn == "turn":
        x, y = x - 0.12 * a[1], y + 0.12 * a[0]
    elif dyn == "scale":
        side, y = side + 0.06 * a[0], y + 0.04 * a[1]
    elif dyn == "fade":
        bright, x = bright + 0.15 * a[0], x + 0.04 * a[1]
    elif dyn == "orbit":
        dx, dy = x - 0.5, y - 0.5
        r = np.hypot(dx, dy) + 0.03 * a[1]
        th = np.arctan2(dy, dx) + 0.25 * a[0]
        x, y = 0.5 + r * np.cos(th), 0.5 + r * np.sin(th)
    elif dyn == "drift":
        x, y = x - 0.12 * a[0], y + 0.12 * a[1] + 0.02
    else:
        raise ValueError(f"unknown dynamics {dyn!r}; known: {DYNAMICS}")
    return np.array([np.clip(x, 0.15, 0.85), np.clip(y, 0.15, 0.85), np.clip(side, 0.25, 0.7), np.clip(bright, 0.3, 1.4)],
                    np.float32)


def episode(dyn: str, color: np.ndarray, seed: int, n_actions: int, size: int) -> dict[str, np.ndarray]:
    """One episode in the store's convention: n_actions + 1 rows, row t's action produced row t + 1; the last
    row's action is padding (a copy of the one before)."""
    rng = np.random.default_rng(seed)
    st, actions = _random_walk(lambda s, a: _step(dyn, s, a), np.array([*rng.uniform(0.25, 0.75, 2), 0.45, 1.0],
                                                                      np.float32), rng, n_actions)
    return {"image": _render(st, color, size), "state": st, "action": actions}


def _random_walk(step, s: np.ndarray, rng: np.random.Generator, n_actions: int) -> tuple[np.ndarray, np.ndarray]:
    """States (n_actions + 1, D) and actions (n_actions + 1, 2) of a smooth random walk of actions in [-1, 1]^2
    driving `step(state, action)`; the last action is padding (a copy of the one before)."""
    a = rng.uniform(-1, 1, 2)
    states, actions = [s], []
    for _ in range(n_actions):
        a = np.clip(0.7 * a + 0.5 * rng.normal(size=2), -1, 1)
        actions.append(a.astype(np.float32))
        s = step(s, a)
        states.append(s)
    actions.append(actions[-1])
    return np.stack(states), np.stack(actions)


def _check_group(kind: str, kinds: tuple[str, str], n_tasks: int, most: int) -> None:
    if kind not in kinds:
        raise ValueError(f"kind={kind!r}: expected {kinds[0]} or {kinds[1]}")
    if not 1 <= n_tasks <= most:
        raise ValueError(f"n_tasks={n_tasks}: expected 1..{most}")


def make_group(kind: str, n_tasks: int, episodes: int, n_actions: int, size: int, seed: int = 0) -> ArraySource:
    """A group of n_tasks tasks x episodes episodes: kind "shared" (every task `move`) or "diverse" (the first
    n_tasks DYNAMICS). Task i has colour i and the same episode seeds in both kinds, so task 0 (`move` in both) is
    the same data in both groups and only the dynamics of the other tasks differ."""
    _check_group(kind, ("shared", "diverse"), n_tasks, len(DYNAMICS))
    infos, arrays = [], []
    for t in range(n_tasks):
        dyn = "move" if kind == "shared" else DYNAMICS[t]
        for e in range(episodes):
            ep_seed = int(np.random.default_rng([seed, t, e]).integers(2**31))
            arrays.append(episode(dyn, COLORS[t], ep_seed, n_actions, size))
            infos.append(EpisodeInfo(task=f"{kind}-{t}-{dyn}", seed=e, group=kind, n_rows=n_actions + 1,
                                     action_space=ACTION_SPACE))
    return ArraySource(infos, arrays)


def write_group(store_root, kind: str, n_tasks: int, episodes: int, n_actions: int, size: int, seed: int = 0,
                pipeline: str = "synthetic") -> list:
    """Write a group (make_group) into an episode store as `<pipeline>/<task>` episodes of group `kind`, camera
    "front"; returns the paths. For end-to-end runs of src/diversity.py without the simulator."""
    from simeval.episodes.store import Episode, EpisodeStore

    src = make_group(kind, n_tasks, episodes, n_actions, size, seed)
    store, paths = EpisodeStore(store_root), []
    for info, a in zip(src.infos, src.arrays):
        n = info.n_rows
        ep = Episode(pipeline=pipeline, task=info.task, description=f"synthetic {info.task}", group=kind,
                     seed=info.seed, rgb={"front": a["image"]}, state=a["state"], action=a["action"],
                     reward=np.zeros(n, np.float32), is_first=np.arange(n) == 0, is_terminal=np.arange(n) == n - 1,
                     action_space=dict(ACTION_SPACE), state_names=["x", "y", "side", "brightness"], source="synthetic")
        paths.append(store.write(ep))
    return paths


# (gain, friction, restitution, turn in degrees): PHYSICS[0] is the shared group's; each other differs in 2-4 knobs
PHYSICS = ((0.030, 0.20, 0.5, 0.0), (0.060, 0.05, 0.9, 0.0), (0.015, 0.45, 0.1, 0.0), (0.030, 0.20, 0.5, 90.0),
           (0.045, 0.10, 0.8, -120.0), (0.025, 0.30, 0.2, 180.0))
PHYSICS_COLOR = np.array([230, 60, 60], np.float32)
PHYSICS_SIDE = 0.22


def physics_step(params: tuple[float, float, float, float], s: np.ndarray, a: np.ndarray) -> np.ndarray:
    """One control step of the dynamics-only control (see the module docstring): (4,) state -> (4,) state."""
    gain, friction, restitution, turn = params
    c, d = np.cos(np.radians(turn)), np.sin(np.radians(turn))
    v = (1 - friction) * s[2:] + gain * np.array([c * a[0] - d * a[1], d * a[0] + c * a[1]])
    p = s[:2] + v
    for i in range(2):
        for wall in (0.15, 0.85):
            if (p[i] - wall) * (1 if wall > 0.5 else -1) > 0:
                p[i], v[i] = 2 * wall - p[i], -restitution * v[i]
    return np.array([*p, *v], np.float32)


def physics_episode(params, seed: int, n_actions: int, size: int) -> dict[str, np.ndarray]:
    """One dynamics-only episode (same conventions as `episode`); the square's look never depends on `params`."""
    rng = np.random.default_rng(seed)
    st, actions = _random_walk(lambda s, a: physics_step(params, s, a),
                               np.array([*rng.uniform(0.3, 0.7, 2), 0.0, 0.0], np.float32), rng, n_actions)
    look = np.stack([st[:, 0], st[:, 1], np.full(len(st), PHYSICS_SIDE), np.ones(len(st))], 1).astype(np.float32)
    return {"image": _render(look, PHYSICS_COLOR, size), "state": st, "action": actions}


def _group(name: str, kind: str, n_tasks: int, looks: tuple, episodes: int, n_actions: int, seed: int,
           episode: Callable[[object, int], dict]) -> ArraySource:
    """Tasks 0..n_tasks-1 of a control group: task i's episode e is episode(looks[0] if kind is "shared" else
    looks[i], its seed); the seeds are the same in both kinds, so the kinds differ in the looks (physics, arm) alone."""
    _check_group(kind, ("shared", "varied"), n_tasks, len(looks))
    infos, arrays = [], []
    for t in range(n_tasks):
        look = looks[0] if kind == "shared" else looks[t]
        for e in range(episodes):
            arrays.append(episode(look, int(np.random.default_rng([seed, t, e, 1]).integers(2**31))))
            infos.append(EpisodeInfo(task=f"{name}-{kind}-{t}", seed=e, group=kind, n_rows=n_actions + 1,
                                     action_space=ACTION_SPACE))
    return ArraySource(infos, arrays)


def make_physics_group(kind: str, n_tasks: int, episodes: int, n_actions: int, size: int,
                       seed: int = 0) -> ArraySource:
    """A dynamics-only group: kind "shared" (every task PHYSICS[0]) or "varied" (task i PHYSICS[i]). Task i has the
    same episode seeds (initial positions and pushes) in both kinds, so the groups differ in physics alone."""
    return _group("physics", kind, n_tasks, PHYSICS, episodes, n_actions, seed,
                  lambda params, ep_seed: physics_episode(params, ep_seed, n_actions, size))


# Visual only (`make_visual_group`): the dynamics-only square with PHYSICS[0] in every task, and an "arm": a bar from
# the top edge down to the point the action commands, (0.5, 0.5) + 0.35 a, drawn over the square (as a robot
# occludes what it pushes) and masked as the robot. A "shared" group draws every task's arm alike; a "varied"
# group gives task i the arm look ARM_LOOKS[i] (colour and texture). Physics and objects are identical: only the
# robot's appearance differs, which an object-focused error (robot pixels excluded) must not see.
ARM_LOOKS = (((70, 70, 80), "solid"), ((240, 240, 90), "stripes"), ((60, 200, 240), "checker"),
             ((250, 150, 40), "columns"), ((200, 80, 220), "stripes"), ((120, 240, 120), "checker"))
ARM_WIDTH = 0.12


def _texture(kind: str, size: int) -> np.ndarray:
    """(size, size) brightness factors of an arm texture."""
    r, c = np.indices((size, size))
    if kind == "solid":
        return np.ones((size, size), np.float32)
    if kind == "stripes":
        return np.where((r // 2) % 2 == 0, 1.0, 0.45).astype(np.float32)
    if kind == "columns":
        return np.where((c // 2) % 2 == 0, 1.0, 0.45).astype(np.float32)
    if kind == "checker":
        return np.where(((r // 3) + (c // 3)) % 2 == 0, 1.0, 0.4).astype(np.float32)
    raise ValueError(f"unknown texture {kind!r}")


def draw_arm(frames: np.ndarray, tips: np.ndarray, look) -> tuple[np.ndarray, np.ndarray]:
    """Draw the arm over (n, H, W, 3) frames for (n, 2) tips (x, y in [0, 1]); returns (frames, robot masks (n, H,
    W) bool: every pixel the bar covers at all)."""
    size = frames.shape[1]
    grid = (np.arange(size, dtype=np.float32) + 0.5) / size
    x, y = tips[:, 0][:, None], tips[:, 1][:, None]
    lo, hi = grid[None] - 0.5 / size, grid[None] + 0.5 / size
    cover_x = np.clip(np.minimum(hi, x + ARM_WIDTH / 2) - np.maximum(lo, x - ARM_WIDTH / 2), 0, 1 / size) * size
    cover_y = np.clip(np.minimum(hi, y) - np.maximum(lo, 0.0), 0, 1 / size) * size
    alpha = cover_y[:, :, None] * cover_x[:, None, :]  # (n, H, W)
    color, texture = np.asarray(look[0], np.float32), _texture(look[1], size)
    arm = color[None, None, None] * texture[None, :, :, None]
    out = frames.astype(np.float32) * (1 - alpha[..., None]) + arm * alpha[..., None]
    return np.clip(np.round(out), 0, 255).astype(np.uint8), alpha > 0


def make_visual_group(kind: str, n_tasks: int, episodes: int, n_actions: int, size: int,
                      seed: int = 0) -> ArraySource:
    """A visual-only group (see ARM_LOOKS): kind "shared" (every task's arm ARM_LOOKS[0]) or "varied" (task i's
    ARM_LOOKS[i]); the same physics, square and episode seeds in both kinds. Episodes carry `robot_mask`."""

    def episode(look, ep_seed: int) -> dict:
        ep = physics_episode(PHYSICS[0], ep_seed, n_actions, size)
        a = ep["action"]
        # row t shows the arm where the action that produced it pointed (row 0: where the first action points)
        commanded = np.concatenate([a[:1], a[:-1]])
        tips = np.clip(0.5 + 0.35 * commanded, 0.05, 0.95)
        ep["image"], ep["robot_mask"] = draw_arm(ep["image"], tips, look)
        return ep

    return _group("visual", kind, n_tasks, ARM_LOOKS, episodes, n_actions, seed, episode)
