"""Declarative task specs (YAML) and the sampling of a task instance from a seed.

    name: place-red-in-green
    group: placement
    description: "Put every {block.color} block into the {bowl.color} bowl."   # fields: <object>.color / .count
    end_effector: suction            # suction | spatula
    objects:
      - {name: block, shape: block, colors: [red], count: [1, 3], size: [0.04, 0.04, 0.04]}
      - {name: bowl, shape: bowl, colors: [green], count: 1, size: [0.12, 0.12, 0.05]}
      - {name: distractor, shape: block, colors: [blue, yellow], count: [0, 2], distractor: true}
    goals:
      - {type: in_container, what: block, where: bowl}
    max_primitives: 8

Knobs a generalization test varies, all per episode seed: colours (one of `colors`, per object name unless
`color_per_instance`), counts (`count: [lo, hi]`), poses (uniform over `region` or the workspace, random yaw),
distractors (objects with `distractor: true`), and the robot's start (`home_noise`, radians).
Goal types: in_zone, in_container (each `what` instance in some `where` instance; `each: true` asks for a
one-to-one assignment, "one ball into each zone"), stack (`what`: names, each resting on the previous), on_objects
(`what` resting on all `where` instances, e.g. a bridge deck), at_offset (`what` at `offset` [dx, dy] from the first
`where` instance, index-matched: instance i at offset i), pile_in_zone (`fraction` of the pile's particles in the
zone). `upright: true` on a goal also requires its objects to stand upright (where the text says upright or stand).

Articulated objects (simeval.sim.core.articulated: laptop, lamp, display, faucet, drawer, oven, window, toilet,
dishwasher, table_doors) take `on_table: true` (stands on a wooden table board) and `joint_init` (the initial
position of each of its joints as a fraction of the joint's limits, 0 = closed/lower, 1 = open/upper; one number for
every joint or a list, one per joint). Goal type joint_range: `{type: joint_range, what: <object>, range: [lo, hi]}`
(optionally `joint: k`, the k-th non-fixed joint, default 0) -- done when the joint's fraction is within [lo, hi].

Panda tasks (the BBSEA suite) add `robot: panda`, `action_space: ee_pose` and a `plan`, the task's primitives in
order (`plan: [{open_drawer: drawer}, {pick: block}, {place_in: drawer}]`, simeval.sim.experts.plan). Their
fixtures (simeval.sim.core.fixtures: drawer_cabinet, bin, button) are URDF bodies too; the jointed ones (drawer_cabinet,
button) take `joint_init` and joint_range goals like articulated objects; in_container also takes bins and
drawer cabinets as `where`. The `size` knob ([x, y, z] m) resizes every instance of an object.

Task-level fields: `action_space` (the task's native action space for make_env: joint | pick_place | ee_delta |
ee_pose; default joint) and `initial_state`: `random` (default: layout, colours, sizes and the arm's start drawn from the
episode seed, GenSim's protocol) or `fixed` (RoboGen's protocol: every episode starts from the scene of seed 0, bit
for bit; the seed then drives only what the policy does, e.g. a controller's action noise).

Variation knobs (`check_variation`), all per episode seed: objects' `colors`, `count`, and for articulated objects
`scale` (a factor or [lo, hi]: the object's overall size times a factor drawn uniformly) and `joint_init_noise`
(fraction: each joint's initial fraction moved by a uniform draw in [-x, x], clipped to [0, 1]); for loose objects
(blocks, cylinders, spheres, piles: every particle alike) `friction` (a coefficient or [lo, hi]: the lateral friction of each instance, drawn
uniformly; the default is 0.8, and PyBullet multiplies it by the table's 0.6: how far a pushed block slides on
after the push, a property the camera cannot see before it moves, the dynamics dose of the controls); `robot:
{home_noise}` (radians); `scene: {initial_state: random}` (a `fixed` task's scene drawn from the episode seed, as
test-time variation does; without it a fixed task ignores the seed whatever the other knobs say) and `scene:
{pose_range}` (a fraction in [0, 1]: how far the poses may stray from one anchor layout per task; a diversity dose
for the dynamics-diversity controls, see sample_instance).

Every task draws from its own random stream, seeded by (task name, seed): the same episode seed gives unrelated
layouts in different tasks. A layout that does not fit is redrawn from the same stream, so every seed is valid.
Counts in a `variation` must agree with the text and goals (see `valid_counts`).
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import yaml

from simeval.errors import UserError
from simeval.sim.core.articulated import ARTICULATED, n_joints
from simeval.sim.core.objects import COLORS, SHAPES, SimObject
from simeval.sim.core.world import WORKSPACE

ACTION_SPACE_NAMES = ("joint", "pick_place", "ee_delta", "ee_pose")  # a task's native action space (simeval.sim.env)
FIXTURE_JOINTED = ("drawer_cabinet", "button")  # simeval.sim.core.fixtures with one joint (joint_init, joint_range)
JOINTED = ARTICULATED + FIXTURE_JOINTED
LOOSE = ("block", "cylinder", "sphere", "pile")  # the `friction` knob's shapes: free on the table (a pile: every particle)
INITIAL_STATES = ("random", "fixed")


class SpecError(UserError):
    pass


@dataclass
class ObjectSpec:
    name: str
    shape: str
    colors: list[str]
    count: tuple[int, int] = (1, 1)
    size: tuple[float, float, float] = (0.04, 0.04, 0.04)
    region: tuple[tuple[float, float], tuple[float, float]] | None = None
    yaw: tuple[float, float] = (-math.pi, math.pi)
    distractor: bool = False
    color_per_instance: bool = False
    color_as: str | None = None  # take the colour of another (earlier) object, e.g. a block matching its zone
    on_table: bool = False  # articulated objects: on a table board
    joint_init: tuple[float, ...] = (0.0,)  # articulated objects: initial joint fractions (one for all, or per joint)


@dataclass
class GoalSpec:
    type: str
    what: list[str]
    where: list[str] = field(default_factory=list)
    offset: list[list[float]] = field(default_factory=list)
    fraction: float = 0.95  # piles: GenSim/Ravens count a pile done at about all particles (reward within 0.01 of max)
    upright: bool = False  # the text says upright / stand: objects must stand on their base
    each: bool = False  # in_zone/in_container: one `what` per `where` instance ("one ball into each zone")
    range: tuple[float, float] = (0.0, 1.0)  # joint_range: the goal's joint fractions
    joint: int = 0  # joint_range: which non-fixed joint of the object
    params: dict = field(default_factory=dict)  # a goal type's own fields (its `fields`, simeval.sim.tasks.goal_types)


@dataclass
class TaskSpec:
    """A task simeval's simulator builds (a suite's YAML file): its objects, goal, plan and variations. The other
    task records (TaskText, NativeTask, TaskBundle) are listed in docs/concepts.md."""
    name: str
    group: str
    description: str
    objects: list[ObjectSpec]
    goals: list[GoalSpec]
    end_effector: str = "suction"
    max_primitives: int = 10
    home_noise: float = 0.0
    source: str = ""
    action_space: str = "joint"  # native action space of make_env
    initial_state: str = "random"  # random | fixed (RoboGen: every episode from the scene of seed 0)
    # test-time variations by split name (only `eval` so far): knobs in check_variation's form (simeval.sim.tasks.splits)
    variations: dict[str, dict] = field(default_factory=dict)
    robot: str = "xarm6"
    plan: list[tuple[str, str]] = field(default_factory=list)  # [(primitive, object name)]: simeval.sim.experts.plan

    def object(self, name: str) -> ObjectSpec:
        for o in self.objects:
            if o.name == name:
                return o
        raise SpecError(f"task {self.name}: no object named '{name}'")


def _pair(v, key: str, where: str) -> tuple:
    if isinstance(v, (int, float)):
        return (v, v)
    if isinstance(v, (list, tuple)) and len(v) == 2:
        return tuple(v)
    raise SpecError(f"{where}: `{key}` must be a number or [low, high], got {v!r}")


def _names(value) -> list[str]:
    """A name or a list of names, as a list."""
    return [value] if isinstance(value, str) else list(value or [])


def _parse_object(o, w: str, earlier: list[ObjectSpec]) -> ObjectSpec:
    if not isinstance(o, dict) or "name" not in o:
        raise SpecError(f"{w}: an object is a mapping with at least `name` and `shape`, got {o!r}")
    if o.get("shape") not in SHAPES:
        raise SpecError(f"{w}: shape {o.get('shape')!r} is not one of {', '.join(SHAPES)}")
    colors = _names(o.get("colors", o.get("color", "gray")))
    bad = [c for c in colors if c not in COLORS]
    if bad:
        raise SpecError(f"{w}: unknown colour(s) {bad}; known: {', '.join(COLORS)}")
    count = tuple(int(x) for x in _pair(o.get("count", 1), "count", w))
    if not 0 <= count[0] <= count[1]:
        raise SpecError(f"{w}: count must satisfy 0 <= low <= high, got {count}")
    if o.get("color_as") and o["color_as"] not in [x.name for x in earlier]:
        raise SpecError(f"{w}: color_as '{o['color_as']}' must name an object listed before it")
    return ObjectSpec(
        name=str(o["name"]), shape=o["shape"], colors=colors, count=count,
        size=tuple(float(x) for x in o.get("size", (0.04, 0.04, 0.04))),
        region=tuple(tuple(r) for r in o["region"]) if o.get("region") else None,
        yaw=tuple(float(x) for x in _pair(o.get("yaw", [-math.pi, math.pi]), "yaw", w)),
        distractor=bool(o.get("distractor", False)), color_per_instance=bool(o.get("color_per_instance", False)),
        color_as=o.get("color_as"), on_table=bool(o.get("on_table", False)),
        joint_init=_joint_init(o.get("joint_init", 0.0), w))


def _joint_init(v, w: str) -> tuple[float, ...]:
    vals = [v] if isinstance(v, (int, float)) and not isinstance(v, bool) else v
    if not isinstance(vals, (list, tuple)) or not vals or any(
            isinstance(x, bool) or not isinstance(x, (int, float)) or not 0 <= x <= 1 for x in vals):
        raise SpecError(f"{w}: joint_init must be a fraction in [0, 1] or a list of them (one per joint), got {v!r}")
    return tuple(float(x) for x in vals)


def _parse_goal(g, w: str, objects: list[ObjectSpec]) -> GoalSpec:
    from simeval.sim.tasks.goal_types import goal_kinds  # one file per goal type

    kinds = goal_kinds()
    if not isinstance(g, dict) or g.get("type") not in kinds:
        raise SpecError(f"{w}: a goal is a mapping whose type is one of {', '.join(sorted(kinds))}, got {g!r}")
    kind = kinds[g["type"]]
    names = [o.name for o in objects]
    what, where = _names(g.get("what")), _names(g.get("where"))
    for n in what + where:
        if n not in names:
            raise SpecError(f"{w}: names object '{n}', not among {names}")
    if g.get("each") and not kind.each:
        each = ", ".join(sorted(k.name for k in kinds.values() if k.each))
        raise SpecError(f"{w}: `each` applies to {each} goals, not {g['type']}")
    extra = kind.fields(g, what, where, {o.name: o for o in objects}, w) if kind.fields else {}
    return GoalSpec(g["type"], what, where, [list(map(float, o)) for o in g.get("offset", [])],
                    float(g.get("fraction", GoalSpec.fraction)), bool(g.get("upright", False)),
                    bool(g.get("each", False)), **extra)


def parse_spec(data: dict, source: str = "") -> TaskSpec:
    if not isinstance(data, dict):
        raise SpecError(f"{source or 'spec'}: a task spec is a mapping, got {type(data).__name__}")
    where = source or data.get("name", "spec")
    missing = [k for k in ("name", "group", "description", "objects", "goals") if k not in data]
    if missing:
        raise SpecError(f"{where}: missing {', '.join(missing)}")
    objects: list[ObjectSpec] = []
    for i, o in enumerate(data["objects"]):
        objects.append(_parse_object(o, f"{where}: objects[{i}]", objects))
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise SpecError(f"{where}: object names must be unique, got {names}")
    goals = [_parse_goal(g, f"{where}: goals[{i}]", objects) for i, g in enumerate(data["goals"])]
    action_space = data.get("action_space", "joint")
    if action_space not in ACTION_SPACE_NAMES:
        raise SpecError(f"{where}: action_space {action_space!r} is not one of {', '.join(ACTION_SPACE_NAMES)}")
    initial_state = data.get("initial_state", "random")
    if initial_state not in INITIAL_STATES:
        raise SpecError(f"{where}: initial_state {initial_state!r} is not one of {', '.join(INITIAL_STATES)}")
    robot = data.get("robot", "xarm6")
    from simeval.sim.robots import robot_kinds  # the robots are PyBullet code: read only where a spec names one

    if robot not in robot_kinds():
        raise SpecError(f"{where}: robot {robot!r} is not one of {', '.join(sorted(robot_kinds()))}")
    spec = TaskSpec(name=str(data["name"]), group=str(data["group"]), description=str(data["description"]),
                    objects=objects, goals=goals, end_effector=data.get("end_effector", "suction"),
                    max_primitives=int(data.get("max_primitives", 10)), home_noise=float(data.get("home_noise", 0.0)),
                    source=source, action_space=action_space, initial_state=initial_state, robot=robot,
                    plan=_parse_plan(data.get("plan", []), where, names))
    spec.variations = _parse_variations(data.get("variations"), spec, where)
    return spec


def joint_count(obj) -> int:
    """Joints of an articulated object or a jointed fixture (one)."""
    return 1 if obj.shape in FIXTURE_JOINTED else n_joints(obj)


def _parse_plan(plan, where: str, names: list[str]) -> list[tuple[str, str]]:
    """`plan: [{open_drawer: drawer}, {pick: block}, {place_in: drawer}]` -> [(primitive, object name)]."""
    from simeval.sim.experts.plan import PRIMITIVES  # the primitives' names live with their code

    if not isinstance(plan, list):
        raise SpecError(f"{where}: plan must be a list of {{primitive: object}}, got {plan!r}")
    out = []
    for i, step in enumerate(plan):
        if not (isinstance(step, dict) and len(step) == 1):
            raise SpecError(f"{where}: plan[{i}] must be one {{primitive: object}}, got {step!r}")
        (prim, obj), = step.items()
        if prim not in PRIMITIVES:
            raise SpecError(f"{where}: plan[{i}]: primitive {prim!r} is not one of {', '.join(PRIMITIVES)}")
        if obj not in names:
            raise SpecError(f"{where}: plan[{i}]: {prim} names object {obj!r}, not among {names}")
        out.append((prim, obj))
    return out


VARIATION_SPLITS = ("eval",)  # the splits a task spec may vary; `train` is the spec itself, `heldout` whole tasks


def _parse_variations(raw, spec: TaskSpec, where: str) -> dict[str, dict]:
    """`variations: {eval: {<object>: {colors, count}, robot: {home_noise}}}`, each checked against the task."""
    if raw is None:
        return {}
    if not isinstance(raw, dict) or set(raw) - set(VARIATION_SPLITS):
        raise SpecError(f"{where}: `variations` is a mapping with the key(s) {', '.join(VARIATION_SPLITS)}, got "
                        f"{raw!r}")
    out = {}
    for split, knobs in raw.items():
        try:
            out[split] = check_variation([spec], knobs)
        except SpecError as e:
            raise SpecError(f"{where}: variations.{split}: {e}") from None
        for name, v in out[split].items():  # counts must fit the text and goals, as for a variation given to collect
            if name != "robot" and "count" in v:
                lo, hi = (v["count"], v["count"]) if isinstance(v["count"], int) else v["count"]
                try:
                    _check_count(spec, name, int(lo), int(hi))
                except SpecError as e:
                    raise SpecError(f"{where}: variations.{split}: {e}") from None
    return out


def load_spec(path: str | os.PathLike) -> TaskSpec:
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as e:
        raise SpecError(f"cannot read task spec {path}: {' '.join(str(e).split())}") from e  # one line, with the
        # YAML error's line, column and what it expected
    return parse_spec(data, str(path))


def load_suite(folder: str | os.PathLike) -> list[TaskSpec]:
    folder = Path(folder)
    # splits.yaml names the groups' held-out tasks (simeval.sim.tasks.splits); every other YAML file is a task
    specs = [load_spec(p) for p in sorted(folder.glob("*.yaml")) if p.name != "splits.yaml"]
    if not specs:
        raise SpecError(f"{folder}: no task specs (*.yaml)")
    return specs


PIPELINES_DIR = Path(__file__).resolve().parents[2] / "pipelines"  # each suite lives with its pipeline


def suite_dir(name: str) -> Path:
    """The folder of simeval's suite `name`: simeval/pipelines/<name>/suite (one YAML spec per task, splits.yaml)."""
    return PIPELINES_DIR / name / "suite"


def suite_dirs() -> dict[str, Path]:
    """{name: folder} of every suite simeval ships."""
    return {p.parent.name: p for p in sorted(PIPELINES_DIR.glob("*/suite")) if p.is_dir()}


def select_specs(specs: list[TaskSpec], tasks: list[str] | str | None = None, group: str = "all") -> list[TaskSpec]:
    """Named tasks, or one group's tasks, or all; unknown names list what exists. Names together with a group
    other than "all" are an error (neither takes precedence). A single name may be given as
    a string (`tasks=stack-two-blocks` on the command line), not only as a one-element list."""
    if isinstance(tasks, str):  # a string is one name, not a sequence of one-letter names
        tasks = [tasks]
    if tasks and group != "all":  # two selections that could disagree: refuse rather than pick one silently
        raise SpecError(f"tasks={list(tasks)} and task_group={group} were both given; tasks= selects by name and "
                        f"task_group= by group: give only one (task_group=all, the default, with tasks=)")
    if tasks:
        unknown = set(tasks) - {s.name for s in specs}
        if unknown:
            raise SpecError(f"unknown task(s) {sorted(unknown)}; available: {', '.join(s.name for s in specs)}")
        return [s for s in specs if s.name in tasks]
    if group == "all":
        return list(specs)
    groups = sorted({s.group for s in specs})
    if group not in groups:
        raise SpecError(f"unknown task_group '{group}'; available: {', '.join(groups)}, all")
    return [s for s in specs if s.group == group]


OBJECT_KNOBS = ("colors", "count", "scale", "joint_init_noise", "size", "friction")  # size: [x, y, z] m, every instance
ROBOT_KNOBS = ("home_noise",)
UNSEEN_KNOBS = ("friction",)  # object knobs a first observation cannot show (dynamics): a variation with one is
# rolled out in the eval split whatever its first observation (simeval.pipelines.base.Pipeline.unseen_knobs)
SCENE_KNOBS = ("initial_state", "pose_range")


def check_variation(specs: list[TaskSpec], variation: dict | None) -> dict:
    """Validate a variation {object name: {colors, count}, robot: {home_noise}} against the tasks it is for and
    return it normalised (a single colour may be given as a string). Every object it names must belong to at
    least one of `specs`; tasks without that object ignore it, so one variation can cover a group of tasks.
    A name no task has is a typo that would otherwise vary nothing: it is an error naming the tasks' objects."""
    if not variation:
        return {}
    if not isinstance(variation, dict):
        raise SpecError(f"variation must be a mapping like {{block: {{colors: [red]}}, robot: {{home_noise: 0.1}}}}, "
                        f"got {variation!r}")
    out: dict = {}
    for name, knobs in variation.items():
        key = f"variation.{name}"
        allowed = ROBOT_KNOBS if name == "robot" else SCENE_KNOBS if name == "scene" else OBJECT_KNOBS
        if not isinstance(knobs, dict):
            raise SpecError(f"{key}: expected a mapping of {', '.join(allowed)}, got {knobs!r}")
        unknown = sorted(set(knobs) - set(allowed))
        if unknown:
            what = "the robot" if name == "robot" else "the scene" if name == "scene" else "an object"
            raise SpecError(f"{key}: unknown knob(s) {unknown}; valid for {what}: {', '.join(allowed)}")
        check = {"robot": _robot_knobs, "scene": _scene_knobs}.get(name)
        out[name] = check(key, knobs) if check else _object_knobs(specs, name, key, knobs)
    return out


def _robot_knobs(key: str, knobs: dict) -> dict:
    noise = knobs.get("home_noise", 0.0)
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or noise < 0:
        raise SpecError(f"{key}.home_noise: expected radians >= 0, got {noise!r}")
    return dict(knobs)


def _scene_knobs(key: str, knobs: dict) -> dict:
    if knobs.get("initial_state", "random") not in INITIAL_STATES:
        raise SpecError(f"{key}.initial_state: expected one of {', '.join(INITIAL_STATES)}, "
                        f"got {knobs['initial_state']!r}")
    pr = knobs.get("pose_range", 1.0)
    if isinstance(pr, bool) or not isinstance(pr, (int, float)) or not 0 <= pr <= 1:
        raise SpecError(f"{key}.pose_range: expected a fraction in [0, 1] (0: every episode the task's "
                        f"one anchor layout, 1: poses uniform over the regions as usual), got {pr!r}")
    return dict(knobs)


def _object_knobs(specs: list[TaskSpec], name: str, key: str, knobs: dict) -> dict:
    """An object's knobs checked against the objects of that name in `specs`, normalised."""
    if not any(name == o.name for s in specs for o in s.objects):
        if len(specs) == 1:
            raise SpecError(f"{key}: task {specs[0].name} has no object '{name}'; its objects: "
                            f"{', '.join(o.name for o in specs[0].objects)} (and robot)")
        per_task = "; ".join(f"{s.name}: {', '.join(o.name for o in s.objects)}" for s in specs)
        raise SpecError(f"{key}: none of the tasks has an object '{name}'; their objects (and robot): {per_task}")
    knobs = dict(knobs)
    if "colors" in knobs:
        colors = [knobs["colors"]] if isinstance(knobs["colors"], str) else knobs["colors"]
        if not isinstance(colors, list) or not colors or any(c not in COLORS for c in colors):
            raise SpecError(f"{key}.colors: expected a list of colours from {', '.join(COLORS)}, "
                            f"got {knobs['colors']!r}")
        knobs["colors"] = list(colors)
    if "count" in knobs:
        c = knobs["count"]
        whole = lambda x: isinstance(x, int) and not isinstance(x, bool)  # noqa: E731
        pair = (c, c) if whole(c) else c
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2 and all(map(whole, pair))
                and 0 <= pair[0] <= pair[1]):
            raise SpecError(f"{key}.count: expected a count >= 0 or [low, high] with 0 <= low <= high, got {c!r}")
    if "scale" in knobs:
        sc = knobs["scale"]
        pair = (sc, sc) if isinstance(sc, (int, float)) and not isinstance(sc, bool) else sc
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in pair) and 0.5 <= pair[0] <= pair[1] <= 1.5):
            raise SpecError(f"{key}.scale: expected a factor or [low, high] within [0.5, 1.5], got {sc!r}")
        knobs["scale"] = [float(pair[0]), float(pair[1])]
    if "joint_init_noise" in knobs:
        jn = knobs["joint_init_noise"]
        if isinstance(jn, bool) or not isinstance(jn, (int, float)) or not 0 <= jn <= 0.5:
            raise SpecError(f"{key}.joint_init_noise: expected a fraction in [0, 0.5], got {jn!r}")
    if "size" in knobs:
        sz = knobs["size"]
        if not (isinstance(sz, (list, tuple)) and len(sz) == 3
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in sz)):
            raise SpecError(f"{key}.size: expected [x, y, z] in metres, each > 0, got {sz!r}")
        knobs["size"] = [float(x) for x in sz]
    if "friction" in knobs:
        fr = knobs["friction"]
        pair = (fr, fr) if isinstance(fr, (int, float)) and not isinstance(fr, bool) else fr
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in pair)
                and 0 < pair[0] <= pair[1] <= 2):
            raise SpecError(f"{key}.friction: expected a coefficient or [low, high] with 0 < low <= high <= 2, "
                            f"got {fr!r}")
        knobs["friction"] = [float(pair[0]), float(pair[1])]
        if not any(o.name == name and o.shape in LOOSE for s in specs for o in s.objects):
            raise SpecError(f"{key}: friction applies to loose objects ({', '.join(LOOSE)}) only")
    if "joint_init_noise" in knobs and not any(
            o.name == name and o.shape in JOINTED for s in specs for o in s.objects):
        raise SpecError(f"{key}: joint_init_noise applies to articulated objects ({', '.join(JOINTED)}) only")
    if "scale" in knobs and not any(
            o.name == name and o.shape in ARTICULATED for s in specs for o in s.objects):
        raise SpecError(f"{key}: scale applies to articulated objects "
                        f"({', '.join(ARTICULATED)}) only")
    return knobs


def scene_seed(spec: TaskSpec, seed: int, variation: dict | None = None) -> int:
    """The seed the scene is drawn from: the episode seed, or 0 for a `fixed` task (RoboGen's protocol) unless the
    variation asks for `scene: {initial_state: random}`."""
    mode = (variation or {}).get("scene", {}).get("initial_state", spec.initial_state)
    return 0 if mode == "fixed" else int(seed)


def variation_for(spec: TaskSpec, variation: dict) -> dict:
    """The part of a (checked) variation that applies to `spec`: the robot and the objects it has."""
    names = {o.name for o in spec.objects} | {"robot", "scene"}
    return {k: v for k, v in variation.items() if k in names}


@dataclass
class Instance:
    """One sampled task instance: objects with colours, sizes and poses, and the rendered description."""

    spec: TaskSpec
    seed: int
    objects: list[SimObject]
    poses: dict[str, tuple[np.ndarray, float]]  # object id -> (xy, yaw)
    description: str
    joints: dict[str, list[float]] = field(default_factory=dict)  # articulated object id -> initial joint fractions
    frictions: dict[str, float] = field(default_factory=dict)  # object id -> lateral friction (the `friction` knob)

    def by_name(self, name: str) -> list[SimObject]:
        return [o for o in self.objects if o.name == name]


def task_seed(task: str, seed: int) -> np.random.SeedSequence:
    """The random stream of one (task, episode seed): a stable hash of the name (not Python's salted hash()),
    so two tasks with the same seed draw unrelated instances and every run draws the same ones."""
    if int(seed) < 0:
        raise SpecError(f"task {task}: seed must be >= 0, got {seed}")
    name_key = int.from_bytes(hashlib.sha256(task.encode("utf-8")).digest()[:8], "little")
    return np.random.SeedSequence([int(seed), name_key])


def valid_counts(spec: TaskSpec, name: str) -> tuple[int, int | None]:
    """The counts of object `name` that its description and goals allow, as (low, high or None = no bound).
    Distractors (or objects neither goals nor text name) and objects whose spec gives a range ("the red
    blocks") may take any count (at least the range's low); an object placed
    at offsets needs one instance per offset; any other fixed count is what the text is written for ("two
    blocks side by side", "both piles", "the block")."""
    o = spec.object(name)
    if "{" + name + ".count}" in spec.description:
        return (0, None)
    for g in spec.goals:
        if g.type == "at_offset" and name in g.what and g.offset:
            return (len(g.offset), len(g.offset))
    in_goals = any(name in g.what + g.where for g in spec.goals)
    if o.distractor or (not in_goals and "{" + name + "." not in spec.description):
        return (0, None)
    if o.count[0] == o.count[1]:
        return o.count
    return (o.count[0], None)


def _check_count(spec: TaskSpec, name: str, lo: int, hi: int) -> None:
    vlo, vhi = valid_counts(spec, name)
    if lo < vlo or (vhi is not None and hi > vhi) or lo > hi:
        valid = f"{vlo}" if vlo == vhi else f"{vlo} or more" if vhi is None else f"{vlo}..{vhi}"
        asked = f"{lo}" if lo == hi else f"[{lo}, {hi}]"
        raise SpecError(f"task {spec.name}: variation count {asked} for '{name}' does not match the task's text and "
                        f"goals; valid counts for '{name}': {valid}")


_LAYOUT_ATTEMPTS = 200  # whole-layout redraws before a spec is declared unplaceable
_TRIES_PER_OBJECT = 100


def sample_instance(spec: TaskSpec, seed: int, variation: dict | None = None, pose_range: float = 1.0) -> Instance:
    """Colours, counts and poses from (task, seed). `variation` may override per object: {name: {colors, count}}.
    `pose_range` in [0, 1] (the `scene: {pose_range}` knob, a diversity dose): each object's position and yaw are
    anchor + pose_range * (uniform draw - anchor), the anchor being one layout of the same objects fixed per task
    (drawn from its own stream); 0 gives every episode the anchor layout, 1 (default) the usual uniform poses,
    between them uniform over the regions shrunk towards the anchor. Colours and counts do not depend on it."""
    rng = np.random.default_rng(task_seed(spec.name, seed))
    variation = variation or {}
    unknown = set(variation) - {o.name for o in spec.objects}
    if unknown:
        raise SpecError(f"task {spec.name}: variation names unknown object(s) {sorted(unknown)}")
    # the draws' order is the task's stream: objects, layout, joints, then frictions
    objects = _draw_objects(spec, variation, rng)
    _check_one_per_place(spec, objects)
    poses = _draw_layout(spec, objects, rng, float(pose_range), seed)
    objects.sort(key=lambda o: (spec.objects.index(spec.object(o.name)), o.index))
    joints = _draw_joints(spec, objects, variation, rng)
    # drawn last, and only where the knob is given, so every other draw of a task stays what it was
    frictions = {obj.id: float(rng.uniform(*variation[obj.name]["friction"])) for obj in objects
                 if "friction" in variation.get(obj.name, {})}
    return Instance(spec, seed, objects, poses, _describe(spec, objects), joints, frictions)


def _draw_objects(spec: TaskSpec, variation: dict, rng: np.random.Generator) -> list[SimObject]:
    """Each object name's count, colours and size (a variation's overrides applied)."""
    used_colors: set[str] = set()
    named_color: dict[str, str] = {}
    objects: list[SimObject] = []
    for o in spec.objects:
        v = variation.get(o.name, {})
        colors = list(v.get("colors", o.colors))
        lo, hi = v.get("count", o.count) if isinstance(v.get("count", o.count), (list, tuple)) else (v["count"],) * 2
        if "count" in v:
            _check_count(spec, o.name, int(lo), int(hi))
        n = int(rng.integers(lo, hi + 1))
        free = [c for c in colors if c not in used_colors] or colors  # distinct colours across names when possible
        if o.color_as:
            chosen = [named_color[o.color_as]] * n
        elif o.color_per_instance:
            chosen = [str(rng.choice(colors)) for _ in range(n)]
        else:
            chosen = [str(rng.choice(free))] * n
        named_color[o.name] = chosen[0] if chosen else (colors[0] if not o.color_as else named_color[o.color_as])
        used_colors.update(chosen)  # zones too: a roof on a pad of its own colour would be hard to see
        size = tuple(float(x) for x in v.get("size", o.size))
        if o.shape in ARTICULATED and "scale" in v:
            size = _scaled(o.size, rng, v["scale"])  # one factor per object name: its instances alike
        objects += [SimObject(o.name, i, o.shape, chosen[i], size, on_table=o.on_table) for i in range(n)]
    return objects


def _check_one_per_place(spec: TaskSpec, objects: list[SimObject]) -> None:
    for g in spec.goals:
        if g.each:
            n_what = sum(o.name in g.what for o in objects)
            n_where = sum(o.name in g.where for o in objects)
            if n_what != n_where:
                raise SpecError(f"task {spec.name}: goal '{g.type}' asks for one {'/'.join(g.what)} per "
                                f"{'/'.join(g.where)}, but the counts are {n_what} and {n_where}; give them equal counts")


def _draw_layout(spec: TaskSpec, objects: list[SimObject], rng: np.random.Generator, pose_range: float,
                 seed: int) -> dict:
    anchor = _anchor_layout(spec, objects) if pose_range < 1 else None  # 1: the usual draws, bit for bit
    for _ in range(_LAYOUT_ATTEMPTS):  # a layout that does not fit is redrawn from the same stream
        poses = _layout(spec, objects, rng, anchor, pose_range)
        if poses is not None:
            return poses
    raise SpecError(f"task {spec.name} seed {seed}: cannot place its {len(objects)} objects without overlap in "
                    f"{_LAYOUT_ATTEMPTS} layouts; enlarge the regions or reduce counts/sizes")


def _draw_joints(spec: TaskSpec, objects: list[SimObject], variation: dict,
                 rng: np.random.Generator) -> dict[str, list[float]]:
    joints: dict[str, list[float]] = {}
    for obj in objects:  # drawn after the layout, so tasks without articulated objects keep their streams
        if obj.shape in JOINTED:
            o, noise = spec.object(obj.name), float(variation.get(obj.name, {}).get("joint_init_noise", 0.0))
            k = joint_count(obj)
            init = list(o.joint_init) * k if len(o.joint_init) == 1 else list(o.joint_init)
            if len(init) != k:
                raise SpecError(f"task {spec.name}: joint_init of '{o.name}' gives {len(o.joint_init)} fractions, "
                                f"a {o.shape} has {k} joint(s)")
            joints[obj.id] = [float(np.clip(f + rng.uniform(-noise, noise), 0, 1)) if noise else f for f in init]
    return joints


def _describe(spec: TaskSpec, objects: list[SimObject]) -> str:
    fields = {}
    for o in spec.objects:
        inst = [x for x in objects if x.name == o.name]
        fields[o.name] = SimpleNamespace(color=inst[0].color if inst else o.colors[0], count=len(inst))
    try:
        return spec.description.format(**fields)
    except (KeyError, AttributeError) as e:
        raise SpecError(f"task {spec.name}: description field {e} is not <object>.color or <object>.count") from e


def _scaled(size, rng: np.random.Generator, scale) -> tuple[float, float, float]:
    factor = float(rng.uniform(scale[0], scale[1]))
    return tuple(float(x) * factor for x in size)


def _anchor_layout(spec: TaskSpec, objects: list[SimObject]) -> dict[str, tuple[np.ndarray, float]]:
    """The layout `pose_range` shrinks towards: the same objects placed from a stream of the task's own that no
    episode seed draws from (task_seed's entropy plus one more word)."""
    rng = np.random.default_rng([*task_seed(spec.name, 0).entropy, 1])
    for _ in range(_LAYOUT_ATTEMPTS):
        poses = _layout(spec, objects, rng)
        if poses is not None:
            return poses
    raise SpecError(f"task {spec.name}: cannot place its {len(objects)} objects without overlap in "
                    f"{_LAYOUT_ATTEMPTS} layouts; enlarge the regions or reduce counts/sizes")


def _layout(spec: TaskSpec, objects: list[SimObject], rng: np.random.Generator, anchor: dict | None = None,
            pose_range: float = 1.0):
    """Poses with no two footprints closer than 2.5 cm, or None when one object found no room. With an `anchor`
    layout, each draw is pulled towards the object's anchor pose (see sample_instance's `pose_range`)."""
    poses: dict[str, tuple[np.ndarray, float]] = {}
    placed: list[tuple[np.ndarray, float]] = []
    for obj in sorted(objects, key=lambda x: -x.footprint):  # big things first: they are hardest to fit
        spec_o = spec.object(obj.name)
        r = obj.footprint
        if spec_o.region:  # an explicit region bounds the object's centre
            (x0, x1), (y0, y1) = spec_o.region
        else:  # the workspace bounds the whole footprint
            (x0, x1), (y0, y1) = ((a + r, b - r) for a, b in WORKSPACE)
        for _ in range(_TRIES_PER_OBJECT):
            xy = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
            if anchor is not None:
                xy = anchor[obj.id][0] + pose_range * (xy - anchor[obj.id][0])
            if all(np.linalg.norm(xy - p) > r + q + 0.025 for p, q in placed):
                break
        else:
            return None
        placed.append((xy, r))
        yaw = float(rng.uniform(*spec_o.yaw)) if obj.shape not in ("sphere", "pile", "bowl") else 0.0
        if anchor is not None:
            yaw = anchor[obj.id][1] + pose_range * (yaw - anchor[obj.id][1])
        poses[obj.id] = (xy, yaw)
    return poses
