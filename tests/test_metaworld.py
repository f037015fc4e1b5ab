"""Meta-World (pipeline=metaworld): its own tasks, experts and MuJoCo renders through the pipeline interface. The
recorded arrays are checked against Meta-World itself (a replay of the stored actions, a render with the robot
hidden), then the three entrypoints run on its episodes at tiny sizes, and its mistakes give one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simeval.episodes.store import EpisodeStore, read_episode
from simeval.errors import UserError
from simeval.pipelines.metaworld.env import MetaworldEnv
from simeval.pipelines.metaworld.native import (
    CAMERAS,
    ML10_TEST,
    STATE_NAMES,
    Cameras,
    MetaworldSettings,
    expert_action,
    import_metaworld,
    make_task_env,
    record_episode,
)
from simeval.pipelines.registry import pipeline_from_config

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}
TASKS = "[reach-v3,drawer-open-v3]"
pytestmark = pytest.mark.timeout(600)


def _run(entrypoint: str, tmp: Path, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / f"{entrypoint}.py"), "pipeline=metaworld",
                           f"hydra.run.dir={tmp / entrypoint}", *args], cwd=tmp, env=env or ENV,
                          capture_output=True, text=True, timeout=500, check=False)


@pytest.fixture(scope="module")
def episode():
    return record_episode("push-v3", 3, MetaworldSettings(), ["top", "front"], (48, 48), (32, 32))


def test_an_expert_episode_is_stored_in_the_stores_convention(episode):
    ep = episode
    assert ep.success and ep.source == "metaworld" and ep.control_hz == 80.0
    n = ep.n_actions
    assert n < 200 and ep.n_steps == n + 1
    assert ep.rgb["top"].shape == (n + 1, 48, 48, 3) and ep.robot_mask["front"].shape == (n + 1, 48, 48)
    assert ep.state.shape == (n + 1, len(STATE_NAMES)) == (n + 1, 39)
    assert np.array_equal(ep.action[n], ep.action[n - 1]) and np.abs(ep.action).max() <= 1.0
    assert ep.is_first[0] and not ep.is_first[1:].any() and ep.is_terminal[n] and not ep.is_terminal[:n].any()
    assert np.allclose(ep.reward[:n], np.diff(ep.progress)) and ep.reward[n] == 0
    assert ep.progress[-1] > ep.progress[0]
    assert ep.scene_views.shape == (4, 32, 32, 3)


def test_the_stored_actions_replayed_in_meta_world_give_the_stored_states(episode):
    """Row t + 1 is what action t produced: Meta-World's own env of the same variant, fed the stored actions."""
    env, obs = make_task_env("push-v3", 3)
    try:
        assert np.allclose(obs, episode.state[0], atol=1e-6)
        for t in range(episode.n_actions):
            obs, _, _, _, info = env.step(episode.action[t])
            assert np.allclose(obs, episode.state[t + 1], atol=1e-5), f"row {t + 1} differs"
        assert info["success"]
    finally:
        env.close()


def test_the_robot_mask_is_exactly_the_pixels_the_robot_covers():
    """Independent of the segmentation render: the pixels that change when the robot's geoms are hidden (MuJoCo's
    geom groups) are the mask's pixels."""
    mujoco, _, _ = import_metaworld()
    env, _ = make_task_env("door-open-v3", 0)
    cams = Cameras(env, ["front", "top"], (64, 64))
    try:
        rgb, masks = cams.render()
        option = mujoco.MjvOption()
        env.model.geom_group[cams.robot_geoms] = 5
        option.geomgroup[5] = 0
        for cam in ("front", "top"):
            cams.renderer.update_scene(env.data, camera=CAMERAS[cam], scene_option=option)
            hidden = np.flipud(cams.renderer.render())
            changed = (hidden != rgb[cam]).any(-1)
            assert 0.05 < masks[cam].mean() < 0.6
            assert (changed & ~masks[cam]).sum() == 0  # nothing outside the mask is the robot's
            assert (masks[cam] & ~changed).sum() <= 0.01 * masks[cam].sum()  # robot pixels the colour of what is behind
    finally:
        cams.close()
        env.close()


def test_a_seed_is_one_variant_the_same_every_time():
    env_a, obs_a = make_task_env("push-v3", 11)
    env_b, obs_b = make_task_env("push-v3", 11)
    env_c, obs_c = make_task_env("push-v3", 12)
    for env in (env_a, env_b, env_c):
        env.close()
    assert np.array_equal(obs_a, obs_b)
    goal = slice(36, 39)
    assert not np.allclose(obs_a[goal], obs_c[goal]) or not np.allclose(obs_a[4:7], obs_c[4:7])


def test_the_environment_for_policies_ends_on_success_and_reports_progress():
    _, _, experts = import_metaworld()
    env = MetaworldEnv("reach-v3", MetaworldSettings(), (32, 32), ["top"], max_steps=150)
    expert = experts["reach-v3"]()
    obs, info = env.reset(seed=4)
    assert obs["rgb"]["top"].shape == (32, 32, 3) and obs["state"].shape == (39,)
    start, total, done = info["progress"], 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(expert_action(expert, obs["state"]))
        total += reward
        done = terminated or truncated
    env.close()
    assert terminated and not truncated and info["success"]
    assert total == pytest.approx(info["progress"] - start, abs=1e-6)
    env = MetaworldEnv("reach-v3", MetaworldSettings(), (32, 32), ["top"], max_steps=3)
    env.reset(seed=4)
    ends = [env.step(np.zeros(4))[2:4] for _ in range(3)]
    env.close()
    assert ends == [(False, False), (False, False), (False, True)]


def test_the_hand_start_variation_moves_only_the_hand():
    env_a, obs_a = make_task_env("push-v3", 5)
    env_b, obs_b = make_task_env("push-v3", 5, hand_init_noise=0.05)
    env_a.close()
    env_b.close()
    assert 0.005 < np.linalg.norm(obs_a[:3] - obs_b[:3]) < 0.1
    assert np.allclose(obs_a[4:7], obs_b[4:7], atol=1e-3) and np.allclose(obs_a[36:], obs_b[36:], atol=1e-3)


def test_splits_follow_ml10_and_the_configured_variation():
    pipe = pipeline_from_config({"name": "metaworld", "kind": "metaworld", "heldout": {"ml10": list(ML10_TEST)},
                                 "eval_variation": {"hand_init_noise": 0.05}, "native": {"max_steps": 50}})
    specs, held = pipe.group_and_heldout("ml10")
    assert len(specs) == 15 and held == list(ML10_TEST)
    train = [s.name for s, _ in pipe.split_tasks(specs, "train", held)]
    assert len(train) == 10 and not set(train) & set(ML10_TEST)
    assert all(v == {"hand_init_noise": 0.05} for _, v in pipe.split_tasks(specs, "eval", held))
    assert [s.name for s, _ in pipe.split_tasks(specs, "heldout", held)] == list(ML10_TEST)
    with pytest.raises(UserError, match="colors.*not a Meta-World variation"):
        pipe.split_tasks(specs, "eval", held, eval_override={"colors": 2})
    with pytest.raises(UserError, match="not in Meta-World's task_group=ml10"):
        pipe.group_and_heldout("ml10", ["stack-blocks"])


@pytest.fixture(scope="module")
def mw_store(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("metaworld")
    r = _run("collect", tmp, f"tasks={TASKS}", "episodes=4", "workers=2", "record.image_size=[32,32]",
             f"store={tmp / 'store'}")
    assert r.returncode == 0, r.stderr[-3000:]
    return tmp / "store"


def test_collect_writes_meta_worlds_episodes_and_resumes(mw_store, tmp_path):
    store = EpisodeStore(mw_store)
    for task in ("reach-v3", "drawer-open-v3"):
        paths = store.paths("metaworld", task)
        assert [p.name for p in paths] == [f"episode_{s:06d}.h5" for s in range(4)]
        assert all(read_episode(p).success for p in paths)
    mtimes = {p: p.stat().st_mtime for p in mw_store.rglob("*.h5")}
    r = _run("collect", tmp_path, f"tasks={TASKS}", "episodes=4", "record.image_size=[32,32]", f"store={mw_store}")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "0 new episodes, 8 already" in r.stdout + r.stderr
    assert {p: p.stat().st_mtime for p in mw_store.rglob("*.h5")} == mtimes


def test_dynamics_diversity_and_generalization_run_on_meta_world(mw_store, tmp_path):
    r = _run("diversity", tmp_path, "debug=tiny", f"store={mw_store}", "episodes=2", "eval_episodes=[3,4]",
             "progress=false")
    assert r.returncode == 0, r.stderr[-3000:]
    values = json.loads((tmp_path / "diversity" / "result.json").read_text())["values"]
    one_step = values["prediction"]["summary"]["one_step"]
    assert values["protocol"]["name"] == "heldout" and values["prediction"]["robot_mask"]
    assert np.isfinite(one_step["model"]["object_error_per_pixel"]) and one_step["frames"] > 0
    r = _run("generalization", tmp_path, "debug=tiny", f"store={mw_store}", f"tasks={TASKS}", "progress=false",
             f"checkpoint_dir={tmp_path / 'ckpt'}")
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads((tmp_path / "generalization" / "result.json").read_text())["values"]
    assert set(result["splits"]) == {"train", "eval", "heldout"}
    assert [t["task"] for t in result["tasks"] if t["split"] == "heldout"] == ["drawer-open-v3"]


@pytest.mark.parametrize(("args", "env", "expect"), [
    (["tasks=[stack-blocks]"], {}, "not in Meta-World's task_group=ml10"),
    (["pipeline.native.render_quality=best"], {}, "render_quality='best': expected fast or full"),
    (["variation.knobs={colors: 2}"], {}, "is not a Meta-World variation"),
    (["record.cameras=[wrist]"], {}, "record.cameras"),
    ([], {"MUJOCO_GL": "osmesa"}, "apt install libosmesa6"),
    ([], {"MUJOCO_GL": "vulkan"}, "MuJoCo cannot start"),
])
def test_mistakes_give_one_line(tmp_path, args, env, expect):
    r = _run("collect", tmp_path, "tasks=[reach-v3]", "episodes=1", "workers=1", f"store={tmp_path / 'store'}",
             *args, env={**ENV, **env})
    assert r.returncode == 2, r.stderr[-2000:]
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and expect in lines[0] and "Traceback" not in r.stderr, r.stderr[-2000:]


def test_an_empty_mujoco_gl_renders_offscreen_as_an_unset_one(tmp_path):
    """`MUJOCO_GL=` (set, empty) is how a script unsets it; mujoco would read it as its onscreen glfw."""
    r = _run("collect", tmp_path, "tasks=[reach-v3]", "episodes=1", "workers=1", "record.image_size=[32,32]",
             f"store={tmp_path / 'store'}", env={**ENV, "MUJOCO_GL": ""})
    assert r.returncode == 0, r.stderr[-2000:]
    assert EpisodeStore(tmp_path / "store").exists("metaworld", "reach-v3", 0)


def test_collect_takes_the_held_out_tasks_alone_and_generalization_names_a_store_that_is_a_file(mw_store, tmp_path):
    r = _run("collect", tmp_path, "tasks=[drawer-open-v3]", "variation=heldout", "episodes=1", "workers=1",
             "record.image_size=[32,32]", f"store={mw_store}")
    assert r.returncode == 0, r.stderr[-2000:]
    assert EpisodeStore(mw_store).exists("metaworld", "drawer-open-v3", 100000)
    afile = tmp_path / "afile"
    afile.write_text("")
    r = _run("generalization", tmp_path, "debug=tiny", f"store={afile}", "tasks=[reach-v3,drawer-open-v3]")
    assert r.returncode == 2 and r.stderr.strip() == (f"error: store={afile}: is a file, not a folder; give the "
                                                      "episode store's folder (default outputs/episodes)")
    r = _run("generalization", tmp_path, "debug=tiny", f"store={mw_store}", "tasks=[reach-v3,drawer-open-v3]",
             "policy.model.action_space=joint", f"checkpoint_dir={tmp_path / 'ckpt'}")
    assert r.returncode == 2 and r.stderr.strip().endswith("set policy.model.action_space=native (the tasks' own: "
                                                           "metaworld)"), r.stderr[-2000:]


def test_text_diversity_says_meta_world_has_no_task_texts(tmp_path):
    r = _run("text_diversity", tmp_path)
    assert r.returncode == 2 and "ships no task descriptions" in r.stderr and "Traceback" not in r.stderr
