"""A pipeline a user adds without editing simeval: a Gymnasium environment of their own (tests/plugin_example/
my_sim.py, copied to a folder outside the checkout) and its yaml (a Pipeline class by `_target_`, or `kind:
gymnasium`), found through PYTHONPATH and hydra.searchpath; collect, diversity and generalization run on it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from helpers import one_line_error

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "tests" / "plugin_example"


@pytest.fixture()
def user(tmp_path) -> Path:
    shutil.copytree(EXAMPLE, tmp_path / "mine")
    return tmp_path


def _run(user: Path, entry: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(user / "mine")}
    return subprocess.run([sys.executable, str(ROOT / "src" / f"{entry}.py"),
                           f"hydra.searchpath=[file://{user / 'mine' / 'conf'}]", f"store={user / 'episodes'}", *args],
                          cwd=user, capture_output=True, text=True, env=env, timeout=900)


def _result(folder: Path) -> dict:
    return json.loads((folder / "result.json").read_text())


@pytest.mark.timeout(900)  # world models, policies and rollouts at tiny sizes: ~2-3 min on 2 busy cores
def test_a_plugin_pipeline_collects_and_runs_diversity_and_generalization(user):
    res = _run(user, "collect", "pipeline=reach", "episodes=6", "record.cameras=[top]", "record.image_size=[32,32]",
               "workers=1", f"hydra.run.dir={user / 'collect'}")
    assert res.returncode == 0, res.stderr[-3000:]
    tasks = _result(user / "collect")["values"]["tasks"]
    assert {t: v["episodes"] for t, v in tasks.items()} == {"reach-right": 6, "reach-left": 6, "reach-up": 6}
    assert all(v["success"] == 6 for v in tasks.values())  # the user's expert reaches every target
    from simeval.episodes.store import EpisodeStore, read_episode

    ep = read_episode(EpisodeStore(user / "episodes").paths("reach", "reach-left")[0])
    assert ep.action_space["kind"] == "gymnasium:my_sim:PointReach-v0" and ep.action.shape[1] == 2
    assert ep.rgb["top"].shape[1:] == (32, 32, 3) and ep.state.shape[1] == 4 and ep.success_known
    assert ep.description == "move the red dot to the green dot on the left" and ep.control_hz == 10

    res = _run(user, "diversity", "pipeline=reach", "camera=top", "debug=tiny", "episodes=4", "eval_episodes=[5,6]",
               f"checkpoint_dir={user / 'ck'}", f"hydra.run.dir={user / 'diversity'}")
    assert res.returncode == 0, res.stderr[-3000:]
    values = _result(user / "diversity")["values"]
    assert values["gate"]["verdict"] and values["state"]["gate"]["verdict"]  # both readings give their verdict
    assert _result(user / "diversity")["identity"]["pipeline"] == "reach"
    # too few episodes: the collect command it suggests finds the plugin's config and records the stored cameras
    res = _run(user, "diversity", "pipeline=reach", "camera=top", "debug=tiny", "episodes=10", "eval_episodes=[11,12]",
               f"hydra.run.dir={user / 'too_few'}")
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr[-3000:]
    assert f"hydra.searchpath=[file://{user / 'mine' / 'conf'}]" in res.stderr
    assert "'record.cameras=[top]'" in res.stderr and "python src/collect.py pipeline=reach" in res.stderr

    res = _run(user, "generalization", "pipeline=reach", "debug=tiny", "policy.model.cameras=[top]",
               "eval.video_camera=top", "episodes_per_task=4", f"checkpoint_dir={user / 'pol'}",
               f"hydra.run.dir={user / 'generalization'}")
    assert res.returncode == 0, res.stderr[-3000:]
    splits = _result(user / "generalization")["values"]["splits"]
    assert set(splits) == {"train", "eval", "heldout"}  # eval: the gain varied; heldout: reach-up
    rows = _result(user / "generalization")["values"]["tasks"]
    assert {(r["split"], r["task"]) for r in rows} >= {("heldout", "reach-up"), ("eval", "reach-left")}
    # the adapter reads no progress (progress: null): unknown, not 0, in the result and the log
    assert all(v["mean_progress"] is None for v in splits.values())
    assert all(e["progress"] is None for r in rows for e in r["episodes"] if not e.get("unvaried"))
    assert "progress unknown" in res.stderr + res.stdout and "progress 0.00" not in res.stderr + res.stdout
    # text diversity reads the descriptions the yaml lists (pipeline.source: config)
    env = {**os.environ, "PYTHONPATH": str(user / "mine")}
    res = subprocess.run([sys.executable, str(ROOT / "src" / "text_diversity.py"), "pipeline=reach",
                          f"hydra.searchpath=[file://{user / 'mine' / 'conf'}]", f"cache_dir={user / 'cache'}",
                          f"hydra.run.dir={user / 'texts'}"], cwd=user, capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr[-3000:]
    assert _result(user / "texts")["values"]["reach"]["n"] == 3
    res = _run(user, "generalization", "pipeline=reach", "policy=random", "policy.model.cameras=[top]",
               "eval.video_camera=top", "eval.seeds=2", "eval.max_steps=10", f"checkpoint_dir={user / 'pol'}",
               f"hydra.run.dir={user / 'random'}")
    assert res.returncode == 0, res.stderr[-3000:]


@pytest.mark.timeout(900)  # world models, policies and rollouts at tiny sizes: ~2-3 min on 2 busy cores
def test_kind_gymnasium_needs_no_code_of_simeval_and_mistakes_are_one_line(user):
    conf = user / "mine" / "conf" / "pipeline"
    config = yaml.safe_load((conf / "reach.yaml").read_text())
    del config["_target_"]
    config.update(name="reach_plain", kind="gymnasium")
    (conf / "reach_plain.yaml").write_text(yaml.safe_dump(config))
    res = _run(user, "collect", "pipeline=reach_plain", "episodes=1", "record.cameras=[top]",
               "record.image_size=[32,32]", "workers=1", "task_group=reach", f"hydra.run.dir={user / 'c'}")
    assert res.returncode == 0, res.stderr[-3000:]

    def broken(name: str, **change) -> str:
        (conf / f"{name}.yaml").write_text(yaml.safe_dump({**config, "name": name, **change}))
        return f"pipeline={name}"

    args = ("episodes=1", "record.cameras=[top]", "record.image_size=[32,32]", "workers=1")
    one_line_error(_run(user, "collect", broken("b1", env={"id": "NoSuchEnv-v9"}), *args),
                   "pipeline.env.id=NoSuchEnv-v9")
    one_line_error(_run(user, "collect", broken("b2", adapter={**config["adapter"], "state": ["pos", "speed"]}),
                        *args), "pipeline.adapter.state: the observation has no key ['speed']")
    one_line_error(_run(user, "collect", broken("b3", adapter={**config["adapter"], "success": "info.done"}), *args),
                   "pipeline.adapter.success=info.done: the env's info has no 'done'")
    one_line_error(_run(user, "collect", broken("b4", _target_="my_sim.NoSuchPipeline"), *args),
                   "pipeline._target_=my_sim.NoSuchPipeline: my_sim (", "has no 'NoSuchPipeline'")
    one_line_error(_run(user, "collect", broken("b5", expert={"_target_": "my_sim.nobody"}), *args),
                   "pipeline.expert._target_=my_sim.nobody: my_sim (", "has no 'nobody'")
    one_line_error(_run(user, "collect", broken("b7", _target_="their_sim.Pipeline"), *args),
                   "pipeline._target_=their_sim.Pipeline: cannot import their_sim", "PYTHONPATH")
    # a kwarg the env refuses in the eval split: named before a policy trains
    res = _run(user, "generalization", broken("b8", eval_variation={"friction": 0.3}), "debug=tiny",
               "policy.model.cameras=[top]", "eval.video_camera=top", "episodes_per_task=1")
    one_line_error(res, "the env refuses its kwargs", "friction", "pipeline.eval_variation")
    assert "train policy" not in res.stderr
    one_line_error(_run(user, "collect", broken("b6", adapter={**config["adapter"], "cameras": {"top": "pixels"}}),
                        *args), "pipeline.adapter.cameras.top='pixels': the observation has no such key")
    # the video's camera is checked before a policy trains (the suites' default, front, is not this env's)
    one_line_error(_run(user, "generalization", "pipeline=reach_plain", "debug=tiny", "episodes_per_task=1"),
                   "eval.video_camera=front: pipeline reach_plain's environment has cameras top")


@pytest.mark.timeout(900)  # world models, policies and rollouts at tiny sizes: ~2-3 min on 2 busy cores
def test_the_scorecard_of_a_plugin_pipeline_rolls_its_policy_out(user):
    res = _run(user, "collect", "pipeline=reach", "episodes=6", "record.cameras=[top]", "record.image_size=[32,32]",
               "workers=1", f"hydra.run.dir={user / 'collect'}")
    assert res.returncode == 0, res.stderr[-3000:]
    env = {**os.environ, "PYTHONPATH": str(user / "mine")}
    res = subprocess.run([sys.executable, str(ROOT / "src" / "evaluate.py"), "environment=reach",
                          f"hydra.searchpath=[file://{user / 'mine' / 'conf'}]", f"episodes.store={user / 'episodes'}",
                          "debug=tiny", f"tables={ROOT / 'outputs' / 'tables'}"], cwd=user, capture_output=True,
                         text=True, env=env, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    card = json.loads((user / "outputs" / "scorecards" / "reach" / "scorecard.json").read_text())
    by = {a["aspect"]: a for a in card["aspects"]}
    assert by["generalization"]["reading"] == "reads", by["generalization"]["line"]
    line = by["generalization"]["line"]
    assert "policy: eval " in line and "heldout " in line and "random: " in line
    assert by["quality"]["value"] == pytest.approx(10.0)  # the expert reached every target
    assert by["text_diversity"]["reading"] == "reads"
    assert "3 distinct task texts of 3 tasks" in by["text_diversity"]["line"]  # reach-right, -left, -up
