"""Every seed valid, seeds independent across tasks, and success as strict as the task text: each case builds
the situation in the simulator by pose (no oracle) and checks the verdict."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from simeval.sim.tasks.spec import suite_dir, SpecError, load_suite, sample_instance, task_seed

SUITE = {s.name: s for s in load_suite(suite_dir("gensim"))}


# --- section 4: sampling ------------------------------------------------------------------------------------
def test_every_seed_of_every_task_samples():
    for spec in SUITE.values():
        for seed in range(200):
            inst = sample_instance(spec, seed)  # raised SpecError for build-bridge 24/31, sweep-pile... 42
            xy = [inst.poses[o.id][0] for o in inst.objects]
            r = [o.footprint for o in inst.objects]
            assert all(np.linalg.norm(xy[i] - xy[j]) > r[i] + r[j] for i in range(len(xy)) for j in range(i))


def _largest_xy(seeds):
    out = {}
    for spec in SUITE.values():
        for seed in seeds:
            inst = sample_instance(spec, seed)
            big = max(inst.objects, key=lambda o: o.footprint)
            out[spec.name, seed] = inst.poses[big.id][0]
    return out


def test_tasks_draw_independent_layouts_for_the_same_seed():
    seeds = range(60)
    xy = _largest_xy(range(61))
    pairs = list(itertools.combinations(SUITE, 2))
    same = np.mean([np.linalg.norm(xy[a, s] - xy[b, s]) < 0.03 for a, b in pairs for s in seeds])
    shifted = np.mean([np.linalg.norm(xy[a, s] - xy[b, s + 1]) < 0.03 for a, b in pairs for s in seeds])
    # with one shared stream the same seed put the largest objects within 3 cm in 34% of task pairs
    assert same < 2 * shifted + 0.01, (same, shifted)


def test_task_seed_is_stable_and_name_dependent():
    a = np.random.default_rng(task_seed("stack-two-blocks", 3)).integers(1 << 30)
    b = np.random.default_rng(task_seed("stack-two-blocks", 3)).integers(1 << 30)
    c = np.random.default_rng(task_seed("build-wall", 3)).integers(1 << 30)
    assert a == b != c
    # a fixed value: the stream must not depend on the interpreter's hash salt
    assert task_seed("x", 0).entropy == [0, int.from_bytes(__import__("hashlib").sha256(b"x").digest()[:8], "little")]


def test_variation_counts_must_match_the_text():
    pyramid = SUITE["stack-block-pyramid"]
    with pytest.raises(SpecError, match=r"stack-block-pyramid.*'base'.*valid counts for 'base': 2"):
        sample_instance(pyramid, 0, {"base": {"count": 3}})
    with pytest.raises(SpecError, match="sweep-two-piles.*valid counts for 'pile': 2"):
        sample_instance(SUITE["sweep-two-piles"], 0, {"pile": {"count": 1}})
    with pytest.raises(SpecError, match="align-balls-in-zones.*valid counts for 'ball': 2"):
        sample_instance(SUITE["align-balls-in-zones"], 0, {"ball": {"count": 3}})
    # free counts stay free: more red blocks, more distractors
    inst = sample_instance(SUITE["place-red-in-green"], 0, {"block": {"count": 4}, "distractor": {"count": 0}})
    assert len(inst.by_name("block")) == 4 and not inst.by_name("distractor")


# --- section 5: success as strict as the text (situations built by pose, no oracle) --------------------------
from simeval.sim.core.objects import make_object  # noqa: E402
from simeval.sim.core.world import TABLE_Z, World  # noqa: E402
from simeval.sim.robots.xarm import Arm  # noqa: E402
from simeval.sim.tasks import goals as G  # noqa: E402


class Scene:
    """A sampled instance built in a fresh world; `put` moves an object to a pose, `verdict` is (progress, success)."""

    def __init__(self, task: str, seed: int = 0, arm: bool = False, variation: dict | None = None):
        self.spec = SUITE[task]
        self.inst = sample_instance(self.spec, seed, variation)
        self.world = World()
        self.arm = Arm(self.world, self.spec.end_effector) if arm else None
        rng = np.random.default_rng(0)
        for o in self.inst.objects:
            xy, yaw = self.inst.poses[o.id]
            make_object(self.world.c, o, xy, yaw, rng, TABLE_Z)
        self.world.settle(30)

    def obj(self, oid: str):
        return next(o for o in self.inst.objects if o.id == oid)

    def put(self, oid: str, xyz, euler=(0.0, 0.0, 0.0), k: int = 0):
        c = self.world.c
        c.resetBasePositionAndOrientation(self.obj(oid).body_ids[k], list(xyz), c.getQuaternionFromEuler(list(euler)))
        c.resetBaseVelocity(self.obj(oid).body_ids[k], [0, 0, 0], [0, 0, 0])

    def pos(self, oid: str):
        return G.pose(self.world, self.obj(oid))[0]

    def suck(self, oid: str):
        """Attach the object to the suction cup where it is (as Arm.suction_on does on contact)."""
        c, tool, body = self.world.c, self.arm.tool, self.obj(oid).body_ids[0]
        tp, to = c.getBasePositionAndOrientation(tool)
        op, oo = c.getBasePositionAndOrientation(body)
        rel_p, rel_o = c.multiplyTransforms(*c.invertTransform(tp, to), op, oo)
        self.arm.grasp = c.createConstraint(tool, -1, body, -1, c.JOINT_FIXED, [0, 0, 0], rel_p, [0, 0, 0], rel_o)
        self.arm.held = body

    def verdict(self, settle: int = 60):
        self.world.step(settle)
        return G.task_progress(self.world, self.inst)

    def close(self):
        self.world.close()


@pytest.fixture
def scene():
    made = []

    def make(*a, **k):
        made.append(Scene(*a, **k))
        return made[-1]

    yield make
    for s in made:
        s.close()


def test_both_balls_in_one_zone_is_not_one_in_each(scene):
    s = scene("align-balls-in-zones")
    z0, z1 = s.pos("zone0"), s.pos("zone1")
    s.put("ball0", [z0[0] - 0.021, z0[1], 0.021])
    s.put("ball1", [z0[0] + 0.021, z0[1], 0.021])
    assert s.verdict() == (0.5, False)  # was (1.0, True)
    s.put("ball1", [z1[0], z1[1], 0.021])
    assert s.verdict() == (1.0, True)


def test_cylinders_on_their_side_are_not_standing(scene):
    s = scene("place-cylinders-on-line")
    line = s.pos("line0")
    cyl = [o.id for o in s.inst.by_name("cylinder")]
    yaw = G.pose(s.world, s.obj("line0"))[1]
    d = np.array([math.cos(yaw), math.sin(yaw)])
    spots = [line[:2] + d * (i - (len(cyl) - 1) / 2) * 0.08 for i in range(len(cyl))]
    for oid, xy in zip(cyl, spots):
        s.put(oid, [*xy, 0.0205], (math.pi / 2, 0.0, yaw))  # lying along the line
    progress, success = s.verdict()
    assert not success and progress == 0.0  # was success
    for oid, xy in zip(cyl, spots):
        s.put(oid, [*xy, 0.031])
    assert s.verdict() == (1.0, True)


def test_a_block_held_above_another_is_not_stacked(scene):
    s = scene("stack-two-blocks", arm=True)
    b = s.pos("base0")
    top_z = b[2] + 0.02 + 0.02 + 0.012  # 1.2 cm above the base block
    s.put("top0", [b[0], b[1], top_z])
    # hold it there with the suction cup: move the tool onto its top face and attach
    s.world.c.resetBasePositionAndOrientation(s.arm.tool, [b[0], b[1], top_z + 0.02 + 0.03], [1, 0, 0, 0])
    s.suck("top0")
    assert G.task_progress(s.world, s.inst) == (0.0, False)  # was (1.0, True): z within 1.5 cm counted
    # not held but floating 1.2 cm up (no contact): still not a stack
    s2 = scene("stack-two-blocks")
    b2 = s2.pos("base0")
    s2.put("top0", [b2[0], b2[1], b2[2] + 0.04 + 0.012])
    s2.world.c.changeDynamics(s2.obj("top0").body_ids[0], -1, mass=0)  # pinned in the air
    assert s2.verdict(settle=5) == (0.0, False)
    s2.world.c.changeDynamics(s2.obj("top0").body_ids[0], -1, mass=0.05)
    s2.put("top0", [b2[0], b2[1], b2[2] + 0.0405])
    assert s2.verdict() == (1.0, True)


def test_upright_cylinders_touching_the_bowl_wall_are_in_the_bowl(scene):
    s = scene("put-cylinders-in-bowl", variation={"cylinder": {"count": 2}})
    bowl = s.obj("bowl0")
    bp = s.pos("bowl0")
    cyl = s.inst.by_name("cylinder")
    inner = bowl.size[0] / 2 - 0.006
    r = cyl[0].size[0] / 2
    for k, o in enumerate(cyl):  # touching the wall: centre at inner - r = 0.0515 m from the axis
        a = math.pi * k
        s.put(o.id, [bp[0] + (inner - r) * math.cos(a), bp[1] + (inner - r) * math.sin(a), 0.005 + 0.025 + 0.001])
    assert s.verdict() == (1.0, True)  # was 0 (0.5 with one nearer the axis): the test used 0.050 m from the centre


def test_nothing_counts_while_on_the_suction_cup_and_no_flicker_across_release(scene):
    s = scene("put-block-in-zone", arm=True)
    z = s.pos("zone0")
    c = s.world.c
    s.put("block0", [z[0], z[1], 0.02 + 0.006])  # 6 mm above the table, as the oracle lets go
    c.resetBasePositionAndOrientation(s.arm.tool, [z[0], z[1], 0.046 + 0.03], [1, 0, 0, 0])
    c.changeDynamics(s.arm.tool, -1, mass=0)  # keep the cup (and block) still in place of the arm's motors
    s.suck("block0")
    held = [G.task_progress(s.world, s.inst)[0] for _ in range(10) if s.world.step() is None]
    assert max(held) == 0.0  # was 1.0 for the last steps before release
    s.arm.suction_off()
    trace = [G.task_progress(s.world, s.inst)[0] for _ in range(40) if s.world.step() is None]
    assert trace[-1] == 1.0
    first = trace.index(1.0)
    assert all(p == 1.0 for p in trace[first:]), trace  # one +1, no +1 -1 +1


def test_piles_need_about_all_particles(scene):
    for task in ("sweep-pile-into-zone", "sweep-pile-into-matching-zone", "sweep-two-piles"):
        assert sum(int(o.size[2]) for o in sample_instance(SUITE[task], 0).by_name("pile")) == 50  # as Ravens
    s = scene("sweep-pile-into-zone")
    z = s.pos("zone0")
    pile = s.inst.by_name("pile")[0]
    n = len(pile.body_ids)
    grid = [z[:2] + 0.013 * np.array([k % 8 - 3.5, k // 8 - 3]) for k in range(n)]  # a single layer inside
    inside = int(0.8 * n)  # 80% in: what used to be success after 1-3 pushes
    for k in range(n):
        xy = grid[k] if k < inside else z[:2] + np.array([0.013 * (k - inside) - 0.06, 0.15])
        s.put(pile.id, [*xy, 0.0055], k=k)
    progress, success = s.verdict(120)
    assert not success and progress < 0.9
    for k in range(n):
        s.put(pile.id, [*grid[k], 0.0055], k=k)
    assert s.verdict(120) == (1.0, True)


def test_texts_that_say_upright_or_stand_have_upright_goals():
    import re
    for spec in SUITE.values():
        if re.search(r"\b(upright|stand)\b", spec.description, re.I):
            assert any(g.upright for g in spec.goals), spec.name
