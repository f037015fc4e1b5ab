"""Controls of dynamics diversity drawn at random: groups whose answer is known, with visuals and dynamics drawn
from a seed rather than chosen beside the protocol (the committed controls of simeval.measures.dynamics_diversity.controls.synthetic were built
beside it, and an independent control of one small disk found the metric blind where they passed).

A draw (`draw_control(seed)`) fixes the looks and the dynamics' family:
    objects       1-4 disks or squares, each covering `area` of the frame (2-12% each), colours at random
    background    a random colour, flat, a vertical gradient or a faint checker
    camera        `camera_scale` in [0.6, 1.0]: the arena [0, 1]^2 fills that share of the frame side, centred
    action        (2,) in [-1, 1]^2, a smooth random walk; `action_kind`:
                    force     v <- (1 - damping) v + gain R(rotation) a / mass,  then Coulomb friction:
                              |v| <- max(0, |v| - friction);  p <- p + v
                    velocity  v <- gain R(rotation) a / mass;  p <- p + v
                    pose      target = 0.5 + 0.35 R(rotation) a;  v <- (1 - damping) v + gain (target - p) / mass;
                              p <- p + v
                  at a wall of the arena (radius r inside [0, 1]) the position is reflected and that velocity
                  component becomes -restitution v
Every object responds to the same action with knobs of its own (rotation, gain, damping, restitution, mass,
friction). A draw's `base` knobs are the "shared" group's: every episode of every task. The "varied" group draws
the knobs named in `varied_knobs` anew for each episode (the rest stay the base's), so its dynamics are diverse
and its looks identical to the shared group's: a dynamics-diversity reading must rank varied above shared, or say
that it cannot read. The visual family (`kind="visual"`) instead keeps the base knobs in both groups and gives the
varied group's episodes colours, background and texture of their own: it must not read as more diverse.

Shapes per episode (n = n_actions + 1 rows, store convention: row t's action produced row t + 1, the last row's
action is padding): image (n, S, S, 3) uint8; state (n, 0) (no robot: nothing proprioceptive); object_poses
(n, N, 7): x, y in the arena's [0, 1], z = 0, identity quaternion xyzw; action (n, 2).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from simeval.episodes.dataset import ArraySource, EpisodeInfo

ACTION_KINDS = ("force", "velocity", "pose")
KNOBS = ("rotation", "gain", "damping", "restitution", "mass", "friction")
# the knobs each action kind reads (a varied knob the dynamics ignore would vary nothing)
KNOBS_USED = {"force": KNOBS, "velocity": ("rotation", "gain", "restitution", "mass"),
              "pose": ("rotation", "gain", "damping", "restitution", "mass")}
# where a knob is drawn from (uniform; rotation in degrees, gain relative to the kind's scale)
KNOB_RANGES = {"rotation": (-180.0, 180.0), "gain": (0.5, 2.0), "damping": (0.05, 0.5), "restitution": (0.1, 0.95),
               "mass": (0.5, 2.0), "friction": (0.0, 0.012)}
GAIN_SCALE = {"force": 0.03, "velocity": 0.05, "pose": 0.15}  # gain 1 moves an object a few % of the arena a step
TEXTURES = ("flat", "gradient", "checker")
ACTION_SPACE = {"kind": "control_2d", "dims": ["a0", "a1"], "units": ["1", "1"]}


@dataclass(frozen=True)
class Look:
    colors: tuple[tuple[int, int, int], ...]  # per object
    background: tuple[int, int, int]
    texture: str


@dataclass(frozen=True)
class ControlDraw:
    """One drawn configuration: the looks, the action kind, the base knobs per object, the knobs the varied group
    draws per episode."""

    seed: int
    n_objects: int
    area: float  # each object's share of the frame's pixels
    shape: str  # disk | square
    camera_scale: float
    action_kind: str
    look: Look
    base: tuple[dict, ...]  # per object: {knob: value}
    varied_knobs: tuple[str, ...]
    meta: dict = field(default_factory=dict)

    def describe(self) -> str:
        return (f"draw {self.seed}: {self.n_objects} {self.shape}{'s' * (self.n_objects > 1)} of "
                f"{100 * self.area:.1f}% each, camera {self.camera_scale:.2f}, {self.look.texture} background, "
                f"{self.action_kind} actions, varied knobs {'/'.join(self.varied_knobs)}")

    def to_dict(self) -> dict:
        return asdict(self)


def _color(rng: np.random.Generator) -> tuple[int, int, int]:
    return tuple(int(c) for c in rng.integers(0, 256, 3))


def _distinct_color(rng: np.random.Generator, background: tuple[int, int, int]) -> tuple[int, int, int]:
    """A colour at least 80 levels (L2 over RGB) from the background: an object the camera can see."""
    for _ in range(100):
        c = _color(rng)
        if np.linalg.norm(np.subtract(c, background)) >= 80:
            return c
    return tuple(int(255 - b) for b in background)


def draw_knobs(rng: np.random.Generator, names=KNOBS) -> dict:
    return {k: float(rng.uniform(*KNOB_RANGES[k])) for k in names}


def draw_look(rng: np.random.Generator, n_objects: int) -> Look:
    background = _color(rng)
    return Look(tuple(_distinct_color(rng, background) for _ in range(n_objects)), background,
                str(rng.choice(TEXTURES)))


def draw_control(seed: int) -> ControlDraw:
    """A configuration drawn from `seed` (numpy's default_rng): 1-4 objects of 2-12% of the frame each, colours,
    background, texture, camera scale, action kind, base knobs, and 1-3 of the knobs the action kind reads to vary
    (rotation or gain always among them, so that the varied group's dynamics differ in how actions move objects)."""
    rng = np.random.default_rng([int(seed), 5021])
    n = int(rng.integers(1, 5))
    kind = str(rng.choice(ACTION_KINDS))
    used = KNOBS_USED[kind]
    first = str(rng.choice(["rotation", "gain"]))
    others = [k for k in used if k != first]
    extra = list(rng.choice(others, size=int(rng.integers(0, 3)), replace=False))
    return ControlDraw(seed=int(seed), n_objects=n, area=float(rng.uniform(0.02, 0.12)),
                       shape=str(rng.choice(["disk", "square"])), camera_scale=float(rng.uniform(0.6, 1.0)),
                       action_kind=kind, look=draw_look(rng, n),
                       base=tuple(draw_knobs(rng) for _ in range(n)), varied_knobs=tuple([first, *extra]))


def one_disk_control() -> ControlDraw:
    """The independent control that found the metric blind (issue 50): one coloured disk of radius 8% of the frame
    side (2% of its pixels) on grey, force actions, rotation / gain / damping / restitution varied per episode."""
    return ControlDraw(seed=1_000_000, n_objects=1, area=float(np.pi * 0.08**2), shape="disk", camera_scale=1.0,
                       action_kind="force", look=Look(((220, 60, 50),), (128, 128, 128), "flat"),
                       base=({"rotation": 0.0, "gain": 1.0, "damping": 0.2, "restitution": 0.5, "mass": 1.0,
                              "friction": 0.0},),
                       varied_knobs=("rotation", "gain", "damping", "restitution"))


def radius_of(draw: ControlDraw) -> float:
    """An object's radius (half side for a square) in arena units, from its share of the frame's pixels."""
    share = np.sqrt(draw.area / np.pi) if draw.shape == "disk" else np.sqrt(draw.area) / 2
    return float(share / draw.camera_scale)


def _rotate(deg: float, a: np.ndarray) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([c * a[0] - s * a[1], s * a[0] + c * a[1]])


def step_object(kind: str, knobs: dict, p: np.ndarray, v: np.ndarray, a: np.ndarray,
                radius: float) -> tuple[np.ndarray, np.ndarray]:
    """One control step of one object (the module docstring's dynamics): position, velocity (2,) each."""
    g = GAIN_SCALE[kind] * knobs["gain"] / knobs["mass"]
    if kind == "force":
        v = (1 - knobs["damping"]) * v + g * _rotate(knobs["rotation"], a)
        speed = float(np.linalg.norm(v))
        v = v * max(0.0, speed - knobs["friction"]) / speed if speed > 0 else v
    elif kind == "velocity":
        v = g * _rotate(knobs["rotation"], a)
    elif kind == "pose":
        target = 0.5 + 0.35 * _rotate(knobs["rotation"], a)
        v = (1 - knobs["damping"]) * v + g * (target - p)
    else:
        raise ValueError(f"action_kind={kind!r}: expected one of {ACTION_KINDS}")
    p = p + v
    lo, hi = radius, 1.0 - radius
    for i in range(2):
        if p[i] < lo or p[i] > hi:
            wall = lo if p[i] < lo else hi
            p[i], v[i] = 2 * wall - p[i], -knobs["restitution"] * v[i]
            p[i] = min(max(p[i], lo), hi)  # a fast object past both walls stays inside
    return p, v


def render(draw: ControlDraw, look: Look, positions: np.ndarray, size: int) -> np.ndarray:
    """(n, N, 2) arena positions -> (n, size, size, 3) uint8 frames, objects antialiased by 4x4 supersampling and
    drawn in order (later objects over earlier ones)."""
    n = len(positions)
    sub = 4
    grid = (np.arange(size * sub) + 0.5) / (size * sub)  # frame coordinates in [0, 1]
    gy, gx = np.meshgrid(grid, grid, indexing="ij")
    bg = np.asarray(look.background, np.float32)
    rows = np.linspace(0, 1, size, dtype=np.float32)[:, None, None]
    if look.texture == "gradient":
        base = bg[None, None] * (0.75 + 0.5 * rows) * np.ones((1, size, 1), np.float32)
    elif look.texture == "checker":
        r, c = np.indices((size, size))
        base = bg[None, None] * np.where(((r // 8) + (c // 8)) % 2 == 0, 1.0, 0.85)[..., None]
    else:
        base = np.broadcast_to(bg, (size, size, 3))
    frames = np.repeat(np.clip(base, 0, 255)[None].astype(np.float32), n, 0)
    half = np.sqrt(draw.area / np.pi) if draw.shape == "disk" else np.sqrt(draw.area) / 2  # in frame units
    for j in range(draw.n_objects):
        fx = 0.5 + draw.camera_scale * (positions[:, j, 0] - 0.5)  # arena -> frame
        fy = 0.5 + draw.camera_scale * (positions[:, j, 1] - 0.5)
        dx, dy = gx[None] - fx[:, None, None], gy[None] - fy[:, None, None]
        inside = (dx**2 + dy**2 <= half**2) if draw.shape == "disk" else (
            (np.abs(dx) <= half) & (np.abs(dy) <= half))
        alpha = inside.reshape(n, size, sub, size, sub).mean((2, 4)).astype(np.float32)[..., None]
        frames = frames * (1 - alpha) + np.asarray(look.colors[j], np.float32) * alpha
    return np.clip(np.round(frames), 0, 255).astype(np.uint8)


def control_episode(draw: ControlDraw, knobs: tuple[dict, ...], look: Look, seed: int, n_actions: int,
                    size: int) -> dict[str, np.ndarray]:
    """One episode: {image, state (n, 0), object_poses (n, N, 7), action (n, 2)}; `seed` draws the start positions
    and the actions (the same seed gives the same pushes in either group)."""
    rng = np.random.default_rng([int(seed), 77])
    r = radius_of(draw)
    p = rng.uniform(r + 0.05, 1 - r - 0.05, (draw.n_objects, 2)) if r < 0.4 else np.full((draw.n_objects, 2), 0.5)
    v = np.zeros((draw.n_objects, 2))
    a = rng.uniform(-1, 1, 2)
    positions, actions = [p.copy()], []
    for _ in range(n_actions):
        a = np.clip(0.7 * a + 0.5 * rng.normal(size=2), -1, 1)
        actions.append(a.astype(np.float32))
        for j in range(draw.n_objects):
            p[j], v[j] = step_object(draw.action_kind, knobs[j], p[j], v[j], a, r)
        positions.append(p.copy())
    actions.append(actions[-1])
    pos = np.stack(positions).astype(np.float32)  # (n, N, 2)
    poses = np.zeros((len(pos), draw.n_objects, 7), np.float32)
    poses[..., :2], poses[..., 6] = pos, 1.0
    return {"image": render(draw, look, pos, size), "state": np.zeros((len(pos), 0), np.float32),
            "object_poses": poses, "action": np.stack(actions)}


def make_control_group(draw: ControlDraw, group: str, n_tasks: int = 4, episodes: int = 50, n_actions: int = 40,
                       size: int = 64, kind: str = "dynamics") -> ArraySource:
    """A group of `n_tasks` x `episodes` episodes of a draw: `group` "shared" (the base knobs and look everywhere)
    or "varied"; `kind` "dynamics" (varied: the draw's varied knobs drawn per episode) or "visual" (varied: each
    episode's own colours, background and texture; dynamics the base's). Episode e of task t has the same start and
    actions in both groups, so the groups differ in what `kind` varies alone."""
    if group not in ("shared", "varied"):
        raise ValueError(f"group={group!r}: expected shared or varied")
    if kind not in ("dynamics", "visual"):
        raise ValueError(f"kind={kind!r}: expected dynamics or visual")
    infos, arrays = [], []
    for t in range(n_tasks):
        for e in range(episodes):
            ep_seed = int(np.random.default_rng([draw.seed, t, e, 3]).integers(2**31))
            knobs, look = draw.base, draw.look
            if group == "varied":
                vary = np.random.default_rng([draw.seed, t, e, 4])
                if kind == "dynamics":
                    knobs = tuple({**b, **draw_knobs(vary, draw.varied_knobs)} for b in draw.base)
                else:
                    look = draw_look(vary, draw.n_objects)
            ep = control_episode(draw, knobs, look, ep_seed, n_actions, size)
            ep["variation"] = {"knobs": list(knobs), "look": asdict(look)} if group == "varied" else {}
            arrays.append(ep)
            infos.append(EpisodeInfo(task=f"control{draw.seed}-{kind}-{group}-{t}", seed=e, group=group,
                                     n_rows=n_actions + 1, action_space=ACTION_SPACE))
    return ArraySource(infos, [{k: v for k, v in a.items() if k != "variation"} for a in arrays])


def write_control_group(store_root, draw: ControlDraw, group: str, pipeline: str = "custom",
                        state_xy: bool = False, **kw) -> list:
    """make_control_group written into an episode store as `<pipeline>/<task>` (camera "front"), what a user's
    importer would write; `state_xy` records the objects' (x, y) as obs/state (issue 50's control did) rather than
    an empty state. Returns the paths."""
    from simeval.episodes.store import Episode, EpisodeStore

    src = make_control_group(draw, group, **kw)
    store, paths = EpisodeStore(store_root), []
    for info, a in zip(src.infos, src.arrays):
        n = info.n_rows
        state = a["object_poses"][:, :, :2].reshape(n, -1) if state_xy else a["state"]
        names = [f"object{j}_{c}" for j in range(draw.n_objects) for c in "xy"] if state_xy else []
        ep = Episode(pipeline=pipeline, task=info.task, description=f"random control {info.task}", group=group,
                     seed=info.seed, rgb={"front": a["image"]}, state=state, action=a["action"],
                     reward=np.zeros(n, np.float32), is_first=np.arange(n) == 0, is_terminal=np.arange(n) == n - 1,
                     action_space=dict(ACTION_SPACE), state_names=names, object_poses=a["object_poses"],
                     source="random_control")
        paths.append(store.write(ep))
    return paths
