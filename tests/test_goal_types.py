"""The goal-type registry (simeval.sim.tasks.goal_types): a goal type is one file of that package defining
GOAL = GoalKind(...); specs are parsed, goals checked and the generic oracle planned from that file alone."""

from __future__ import annotations

import pytest
import yaml

import simeval.sim.tasks.goal_types as goal_types
from simeval.sim.env import make_env
from simeval.sim.tasks.spec import suite_dir, SpecError, parse_spec

TOY = '''
from simeval.sim.core.geometry import pose
from simeval.sim.core.world import TABLE_Z
from simeval.sim.tasks.goal_types import GoalKind
from simeval.sim.tasks.spec import SpecError


def units(world, inst, goal, held):
    """Each `what` object's centre at least `height` above the table."""
    return [bool(pose(world, o)[0][2] - TABLE_Z >= goal.params["height"]) for n in goal.what
            for o in inst.by_name(n)]


def fields(g, what, where, objects, w):
    if not isinstance(g.get("height"), (int, float)):
        raise SpecError(f"{w}: above_table needs `height:` in metres, got {g.get('height')!r}")
    return {"params": {"height": float(g["height"])}}


GOAL = GoalKind("above_table", units, fields=fields)
'''


@pytest.fixture
def toy_goal(tmp_path, monkeypatch):
    (tmp_path / "above_table.py").write_text(TOY)
    monkeypatch.setattr(goal_types, "__path__", [*goal_types.__path__, str(tmp_path)])
    goal_types.goal_kinds.cache_clear()
    yield
    goal_types.goal_kinds.cache_clear()


def test_the_suites_goal_types_are_registered():
    kinds = goal_types.goal_kinds()
    assert sorted(kinds) == ["at_offset", "in_container", "in_zone", "joint_range", "on_objects", "pile_in_zone",
                             "stack"]
    assert sorted(k for k, v in kinds.items() if v.each) == ["in_container", "in_zone"]
    assert kinds["joint_range"].plan is None  # the generic oracle does not drive articulations (robogen's does)


def test_a_new_goal_type_is_one_file_that_specs_name_and_the_environment_scores(toy_goal):
    data = yaml.safe_load((suite_dir("gensim") / "build-bridge.yaml").read_text())
    with pytest.raises(SpecError, match="above_table needs `height:`"):
        parse_spec({**data, "goals": [{"type": "above_table", "what": "pillar"}]}, "toy")
    with pytest.raises(SpecError, match="one of above_table, at_offset, in_container"):
        parse_spec({**data, "goals": [{"type": "levitate", "what": "pillar"}]}, "toy")
    # the blocks rest on the table (centre 2.5 cm up): done at a 1 cm bar, not at a 10 cm one
    for height, progress in ((0.01, 1.0), (0.10, 0.0)):
        goal = {"type": "above_table", "what": "pillar", "height": height}
        spec = parse_spec({**data, "goals": [goal]}, "toy")
        env = make_env(spec, "pick_place", image_size=(16, 16), cameras=("top",))
        try:
            _, info = env.reset(seed=0)
            assert info["progress"] == pytest.approx(progress)
        finally:
            env.close()
