"""The generalization splits: held-out tasks per group (splits.yaml), each task's own `eval` variation, and the
`variation` config group of collect.py that stores them."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from simeval.sim.tasks.spec import suite_dir, SpecError, load_suite, parse_spec, sample_instance
from simeval.sim.tasks.splits import group_and_heldout, load_heldout, split_tasks

ROOT = Path(__file__).resolve().parents[1]
GENSIM = suite_dir("gensim")


def _spec(**extra):
    data = {"name": "t", "group": "g", "description": "Put the {block.color} block in the {zone.color} zone.",
            "objects": [{"name": "zone", "shape": "zone", "colors": ["green"], "size": [0.1, 0.1, 0.001]},
                        {"name": "block", "shape": "block", "colors": ["red"]},
                        {"name": "distractor", "shape": "block", "colors": ["blue"], "count": [0, 1],
                         "distractor": True}],
            "goals": [{"type": "in_zone", "what": "block", "where": "zone"}]}
    return parse_spec({**data, **extra}, "t.yaml")


def test_a_spec_carries_its_eval_variation_checked_against_its_objects():
    spec = _spec(variations={"eval": {"block": {"colors": "pink"}, "robot": {"home_noise": 0.1}}})
    assert spec.variations == {"eval": {"block": {"colors": ["pink"]}, "robot": {"home_noise": 0.1}}}
    inst = sample_instance(spec, 3, {"block": spec.variations["eval"]["block"]})
    assert [o.color for o in inst.by_name("block")] == ["pink"] and "pink block" in inst.description
    for bad, match in [({"test": {}}, r"t.yaml: `variations` is a mapping with the key\(s\) eval"),
                       ({"eval": {"blok": {"colors": ["pink"]}}}, r"t.yaml: variations.eval: .*no object 'blok'"),
                       ({"eval": {"block": {"colors": ["mauve"]}}}, r"t.yaml: variations.eval: .*colours"),
                       # "the block": one block is what the text is written for
                       ({"eval": {"block": {"count": 2}}}, r"t.yaml: variations.eval: .*valid counts for 'block': 1")]:
        with pytest.raises(SpecError, match=match):
            _spec(variations=bad)


def _suite(tmp_path, splits_text):
    for name, group in [("a", "g1"), ("b", "g1"), ("c", "g1"), ("d", "g2")]:
        spec = yaml.safe_load((GENSIM / "put-block-in-zone.yaml").read_text())
        spec.update(name=name, group=group)
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(spec))
    (tmp_path / "splits.yaml").write_text(splits_text)
    return tmp_path


def test_splits_file_is_checked_against_the_suite(tmp_path):
    suite = _suite(tmp_path, "g1: {heldout: [c]}\n")
    specs = load_suite(suite)  # splits.yaml is not read as a task
    assert sorted(s.name for s in specs) == ["a", "b", "c", "d"]
    assert load_heldout(suite, specs) == {"g1": ["c"]}
    for text, match in [("g3: {heldout: [a]}", "unknown group 'g3'; the suite's groups: g1, g2"),
                        ("g1: {heldout: [d]}", r"g1.heldout names \['d'\], not tasks of group g1 \(a, b, c\)"),
                        ("g2: {heldout: [d]}", "g2.heldout holds every task of the group"),
                        ("g1: [a]", r"g1: expected \{heldout: \[task, ...\]\}"),
                        ("g1: {heldout: [a", "cannot read")]:
        (suite / "splits.yaml").write_text(text)
        with pytest.raises(SpecError, match=match):
            load_heldout(suite, specs)


def test_each_split_rolls_out_its_own_tasks_and_knobs(tmp_path):
    suite = _suite(tmp_path, "g1: {heldout: [c]}\n")
    specs, held = group_and_heldout(suite, "g1")
    assert held == ["c"]
    assert [(s.name, v) for s, v in split_tasks(specs, "train", held)] == [("a", {}), ("b", {})]
    assert [(s.name, v) for s, v in split_tasks(specs, "heldout", held)] == [("c", {})]
    evals = split_tasks(specs, "eval", held)
    own = yaml.safe_load((GENSIM / "put-block-in-zone.yaml").read_text())["variations"]["eval"]
    assert [s.name for s, _ in evals] == ["a", "b"] and evals[0][1]["block"]["colors"] == own["block"]["colors"]
    override = split_tasks(specs, "eval", held, eval_override={"robot": {"home_noise": 0.3}})
    assert [v for _, v in override] == [{"robot": {"home_noise": 0.3}}] * 2
    with pytest.raises(SpecError, match="none of the tasks has an object 'blok'"):
        split_tasks(specs, "eval", held, eval_override={"blok": {"colors": ["red"]}})
    # an explicit list replaces splits.yaml; holding out the whole group leaves nothing to train on
    assert group_and_heldout(suite, "g1", heldout=["a"])[1] == ["a"]
    with pytest.raises(SpecError, match="must be some but not all"):
        group_and_heldout(suite, "g1", heldout=["a", "b", "c"])
    # a name that is no task is named as such, against the tasks chosen with `tasks=` when there are some
    with pytest.raises(SpecError, match=r"heldout_tasks=\['a', 'nope'\]: \['nope'\] not in task_group=g1 \("):
        group_and_heldout(suite, "g1", heldout=["a", "nope"])
    with pytest.raises(SpecError, match=r"\['c'\] not in tasks=\['a', 'b'\] of task_group=g1"):
        group_and_heldout(suite, "g1", tasks=["a", "b"], heldout=["c"])


def test_every_gensim_task_varies_at_eval_and_every_group_holds_one_out():
    specs = load_suite(GENSIM)
    held = load_heldout(GENSIM, specs)
    assert set(held) == {s.group for s in specs} and all(len(v) == 1 for v in held.values())
    for spec in specs:
        var = spec.variations["eval"]
        assert var["robot"]["home_noise"] > 0  # a perturbed start in every task
        recoloured = [n for n in var if n != "robot" and "colors" in var[n]]
        assert recoloured, spec.name
        # an eval colour that the training distribution never draws for that object: unseen at training time
        assert any(set(var[n]["colors"]) - set(spec.object(n).colors) for n in recoloured), spec.name


def test_collect_variation_eval_stores_each_task_with_its_own_variation(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    store = tmp_path / "store"
    p = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "debug=tiny", "variation=eval",
                        "tasks=[stack-two-blocks,put-block-in-zone]", "episodes=1", "workers=1", f"store={store}",
                        f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, env=env, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr[-2000:]
    from simeval.episodes.store import read_meta
    for task in ("stack-two-blocks", "put-block-in-zone"):
        (path,) = list((store / "gensim" / task).glob("episode_*.h5"))
        meta = read_meta(path)
        assert path.name.startswith("episode_100000.v")  # the eval seeds, stored beside the plain episodes
        own = {k: v for k, v in load_suite(GENSIM)[[s.name for s in load_suite(GENSIM)].index(task)]
               .variations["eval"].items()}
        assert meta["variation"] == json.loads(json.dumps(own))
    p = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "debug=tiny", "variation=heldout",
                        "tasks=[stack-two-blocks]", "episodes=1", f"store={store}",
                        f"hydra.run.dir={tmp_path / 'run2'}"], cwd=ROOT, env=env, capture_output=True, text=True)
    assert p.returncode == 2 and "variation=heldout: none of the selected tasks (stack-two-blocks)" in p.stderr


def test_a_broken_splits_file_is_one_line_with_where_and_why(tmp_path):
    suite = _suite(tmp_path, "g1: {heldout: [c\n")
    with pytest.raises(SpecError) as e:
        load_heldout(suite, load_suite(suite))
    msg = str(e.value)
    assert "\n" not in msg and "splits.yaml" in msg and "line" in msg and "column" in msg


def test_a_non_finite_action_is_refused_not_stepped():
    import numpy as np

    from simeval.errors import UserError
    from simeval.sim.env import make_env

    for task in ("open-laptop", "bbsea-open-drawer"):
        env = make_env(task, image_size=(16, 16), cameras=("top",))
        env.reset(seed=0)
        bad = env.action_space.sample()
        bad[0] = np.nan
        with pytest.raises(UserError, match="non-finite"):
            env.step(bad)
        obs, *_ = env.step(env.action_space.sample())  # the environment is still usable
        assert np.all(np.isfinite(obs["state"]))
        env.close()
