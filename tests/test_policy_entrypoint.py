"""src/generalization.py end to end on a small store, its debug overlay, and resuming after kill -9."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import GROUP, synthetic_store
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from simeval.episodes.store import EpisodeStore
from simeval.sim.tasks.spec import suite_dir, load_suite, select_specs

ROOT = Path(__file__).resolve().parents[1]


def h5py_attr(path, key):
    import h5py

    with h5py.File(path, "r") as f:
        return f.attrs[key]


def run(*args, **kw):
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.run([sys.executable, str(ROOT / "src" / "generalization.py"), *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=280, **kw)


def test_debug_overlay_policy_is_the_tiny_preset():
    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        via_debug = compose("generalization", overrides=["debug=tiny"]).policy
        via_group = compose("generalization", overrides=["policy=tiny"]).policy
        cpu = compose("generalization").policy
    assert OmegaConf.to_container(via_debug) == OmegaConf.to_container(via_group)
    assert cpu.name == "cpu" and cpu.model.num_inference_steps == 16 and list(cpu.model.down_dims) == [64, 128, 256]


def test_the_chance_baseline_renders_what_the_policies_beside_it_render():
    """The eval split leaves out a scene whose first observation, as rendered for the policy, is its train scene's;
    a baseline rendering smaller frames leaves out scenes its policy row keeps (at 32x32 one recoloured mix-piles
    scene of GenSim's looked unchanged), so the two rows would not be read on the same scenes."""
    from simeval.measures.generalization.random_baseline import RandomActions

    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        views = {name: compose("generalization", overrides=[f"policy={name}"]).policy.model
                 for name in ("random", "cpu", "authors_gensim_cpu", "authors_gensim")}
    for name, model in views.items():
        assert (list(model.cameras), list(model.image_size)) == (["top"], [64, 64]), name
    default = RandomActions("joint").cfg  # the library's default, for callers without Hydra
    assert (default.cameras, default.image_size) == (["top"], [64, 64])


def test_the_random_action_baseline_runs_from_the_command_line_without_a_training_section(tmp_path):
    """policy=random (conf/policy/random.yaml has no train:) rolls out uniform random actions and writes a result
    with no training: the chance row of Table 5 (a regression once: the entrypoint read policy.train)."""
    out = tmp_path / "run"
    p = run("policy=random", "pipeline=bbsea", "task_group=drawer", "tasks=[bbsea-close-drawer]", "heldout_tasks=[]",
            "eval.splits=[train]", "eval.seeds=1", "eval.max_steps=3", f"checkpoint_dir={tmp_path / 'ckpt'}",
            f"store={tmp_path / 'no-store'}", "progress=false", f"hydra.run.dir={out}")
    assert p.returncode == 0, p.stderr[-2000:]
    rec = json.loads((out / "result.json").read_text())
    assert rec["identity"]["policy"] == "random" and rec["values"]["training"] is None
    assert rec["values"]["splits"]["train"]["success"]["n"] == 1


def test_entrypoint_trains_compares_samplers_and_writes_a_result(tmp_path):
    store = synthetic_store(tmp_path / "store")
    out = tmp_path / "run"
    p = run("debug=tiny", f"store={store}", f"task_group={GROUP}", f"checkpoint_dir={tmp_path / 'ckpt'}",
            "eval.splits=[]", f"hydra.run.dir={out}")
    assert p.returncode == 0, p.stderr[-2000:]
    rec = json.loads((out / "result.json").read_text())
    assert rec["identity"]["task_group"] == GROUP and rec["identity"]["policy"] == "tiny"
    tr = rec["values"]["training"]
    # the suite's splits.yaml holds sweep-two-piles out: the policy trains on the group's other 2 tasks
    assert rec["identity"]["heldout_tasks"] == ["sweep-two-piles"]
    assert tr["steps"] == 20 and len(tr["trained_tasks"]) == 2 and tr["windows"] == 2 * 2 * 29  # 30 rows: 29 actions (row 29's is padding)
    assert set(rec["values"]["sampler_check"]) == {"ddpm", "ddim"}
    ckpt = torch.load(tr["checkpoint"], weights_only=False)
    assert ckpt["policy_config"]["horizon"] == 8 and ckpt["step"] == 20  # the checkpoint carries its config
    logged = (out / "metrics.csv").read_text()
    assert "train/loss" in logged


def test_user_mistakes_are_one_line(tmp_path):
    store = synthetic_store(tmp_path / "store", per_task=1)
    p = run("debug=tiny", f"store={store}", f"task_group={GROUP}", "heldout_tasks=[build-bridge]",
            f"hydra.run.dir={tmp_path / 'a'}")
    assert p.returncode == 2 and "heldout_tasks" in p.stderr and "Traceback" not in p.stderr
    p = run("debug=tiny", f"store={store}", f"task_group={GROUP}", f"hydra.run.dir={tmp_path / 'b'}")
    assert p.returncode == 2 and "fewer than episodes_per_task=2" in p.stderr
    # debug=tiny sets the whole policy node: with policy=random it would train the tiny policy and report it as chance
    p = run("debug=tiny", "policy=random", f"store={store}", f"task_group={GROUP}", f"hydra.run.dir={tmp_path / 'c'}")
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "Traceback" not in p.stderr
    assert p.stderr.startswith("error: policy=random is replaced by policy 'tiny'") and "eval.seeds=2" in p.stderr
    assert not (tmp_path / "c" / "result.json").exists()


def test_a_killed_training_resumes_to_the_same_weights(tmp_path):
    store = synthetic_store(tmp_path / "store")
    common = ["debug=tiny", f"store={store}", f"task_group={GROUP}", "eval.splits=[]", "eval.sampler_check=false",
              "policy.train.train_steps=120", "policy.train.checkpoint_every=5"]
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    killed = subprocess.Popen([sys.executable, str(ROOT / "src" / "generalization.py"), *common,
                               f"checkpoint_dir={tmp_path / 'k'}", f"hydra.run.dir={tmp_path / 'r1'}"],
                              cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 200
    while not list((tmp_path / "k").glob("*/last.ckpt")) and time.time() < deadline and killed.poll() is None:
        time.sleep(0.05)
    os.kill(killed.pid, signal.SIGKILL)
    killed.wait()
    (ckpt,) = list((tmp_path / "k").glob("*/last.ckpt"))
    step_at_kill = torch.load(ckpt, weights_only=False)["step"]
    assert 0 < step_at_kill < 120
    resumed = run(*common, f"checkpoint_dir={tmp_path / 'k'}", f"hydra.run.dir={tmp_path / 'r2'}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"at step {step_at_kill}/120" in (tmp_path / "r2" / "generalization.log").read_text()
    fresh = run(*common, f"checkpoint_dir={tmp_path / 'f'}", f"hydra.run.dir={tmp_path / 'r3'}")
    assert fresh.returncode == 0, fresh.stderr[-2000:]
    a = torch.load(ckpt, weights_only=False)
    (b_path,) = list((tmp_path / "f").glob("*/last.ckpt"))
    b = torch.load(b_path, weights_only=False)
    assert a["step"] == b["step"] == 120
    for k in b["ema_model"]:
        torch.testing.assert_close(a["ema_model"][k], b["ema_model"][k], rtol=1e-5, atol=1e-6, msg=k)


def test_trains_then_rolls_out_through_make_env_on_collected_episodes(tiny_sim_store, tmp_path):
    """On real simulator episodes (src/collect.py debug=tiny, format 2): train a few steps, then roll out through
    make_env on the training split and on a variation, 1 rollout of at most 40 control steps each; success with a
    Wilson interval, progress in range, and a video whose first frame is the environment's reset observation."""
    import imageio.v2 as imageio

    from simeval.sim.env import make_env

    out = tmp_path / "run"
    p = run("debug=tiny", f"store={tiny_sim_store}", "task_group=stacking", "tasks=[stack-two-blocks]",
            f"checkpoint_dir={tmp_path / 'ckpt'}", "eval.splits=[train,eval,heldout]",
            "eval.variation={robot: {home_noise: 0.1}}", f"hydra.run.dir={out}")
    assert p.returncode == 0, p.stderr[-2000:]
    # one task: nothing is held out, and the run says so instead of leaving the split out silently
    assert "split heldout: nothing to roll out (no held-out task), skipped" in p.stdout + p.stderr
    rec = json.loads((out / "result.json").read_text())
    ident, v = rec["identity"], rec["values"]
    assert ident["tasks"] == ["stack-two-blocks"]
    assert ident["variations"] == {"stack-two-blocks": {"robot": {"home_noise": 0.1}}}
    assert v["training"]["steps"] == 20 and v["training"]["trained_tasks"] == ["stack-two-blocks"]
    assert v["training"]["windows"] == sum(
        int(h5py_attr(pth, "n_actions")) for pth in sorted((tiny_sim_store / "gensim" / "stack-two-blocks").glob(
            "episode_*.h5"))[:2])  # (row t, action t) pairs of the 2 training episodes, no padding row
    assert [(r["split"], r["task"]) for r in v["tasks"]] == [("train", "stack-two-blocks"),
                                                             ("eval", "stack-two-blocks")]
    for row in v["tasks"]:
        (ep,) = row["episodes"]
        assert ep["seed"] == 100000 and 0 < ep["steps"] <= 40  # the rollout really stepped the environment
        assert 0.0 <= ep["progress"] <= 1.0 and isinstance(ep["success"], bool)
        s = row["success"]
        assert s["n"] == 1 and s["k"] == int(ep["success"]) and 0 <= s["ci"][0] <= s["rate"] <= s["ci"][1] <= 1
    assert sorted(v["splits"]) == ["eval", "train"]
    for split in ("train", "eval"):
        s = v["splits"][split]["success"]
        assert s["n"] == 1 and 0 <= s["ci"][0] < s["ci"][1] <= 1 and 0 <= v["splits"][split]["mean_progress"] <= 1
    video = Path(v["videos"]["worst"])
    assert video.parent == out / "videos" and video.stat().st_size > 0
    frames = [f for f in imageio.get_reader(video)]  # list() asks the ffmpeg reader its length: inf
    assert len(frames) == v["tasks"][0]["episodes"][0]["steps"] + 1  # the reset frame, then one per step
    env = make_env("stack-two-blocks", action_space="joint", image_size=(32, 32), cameras=("top", "front"))
    obs, _ = env.reset(seed=100000)
    env.close()
    first = frames[0].astype(float)
    assert first.shape == (32, 32, 3) and np.abs(first - obs["rgb"]["front"]).mean() < 8  # mp4 is lossy
    assert np.abs(frames[-1].astype(float) - first).max() > 30  # the arm moved


def test_training_episodes_are_the_plain_ones_by_seed_not_the_varied_ones_beside_them(tmp_path):
    import shutil

    from simeval.measures.generalization.run import episodes_for

    store = EpisodeStore(synthetic_store(tmp_path / "store", per_task=3, T=8))
    task = select_specs(load_suite(suite_dir("gensim")), None, GROUP)[0].name
    plain = store.path_for("gensim", task, 0)
    shutil.copy(plain, plain.with_name("episode_000000.v0123456789.h5"))  # a varied episode's name, stored beside
    train, val, metas = episodes_for(store, "gensim", [task], 2, 1, ["top"])
    assert [e.seed for e in train] == [0, 1] and [e.seed for e in val] == [2]
    assert [m[0] for m in metas] == [f"gensim/{task}/episode_00000{s}.h5" for s in (0, 1)]


def test_successful_demonstrations_pass_over_the_failed_episodes_and_say_how_many_to_collect(tmp_path):
    """demonstrations=successful, as GenSim's demos.py keeps only completed demonstrations: the failed episodes are
    passed over (the next successful ones by seed take their place), an episode whose source records no success
    stays, and too few successes is one error naming each short task's count and a collect size."""
    import h5py

    from simeval.errors import UserError
    from simeval.measures.generalization.run import episodes_for

    store = EpisodeStore(synthetic_store(tmp_path / "store", per_task=5, T=8))
    task = select_specs(load_suite(suite_dir("gensim")), None, GROUP)[0].name
    for seed, success, known in ((0, True, True), (1, False, True), (2, True, True), (3, False, False),
                                 (4, True, True)):
        with h5py.File(store.path_for("gensim", task, seed), "a") as f:
            f.attrs["success"], f.attrs["success_known"] = success, known
    every, every_val, _ = episodes_for(store, "gensim", [task], 3, 1, ["top"])
    assert [e.seed for e in every] == [0, 1, 2] and [e.seed for e in every_val] == [3]
    train, val, metas = episodes_for(store, "gensim", [task], 3, 1, ["top"], "successful")
    assert [e.seed for e in train] == [0, 2, 3] and [e.seed for e in val] == [4]
    assert [m[0] for m in metas] == [f"gensim/{task}/episode_00000{s}.h5" for s in (0, 2, 3)]
    with pytest.raises(UserError) as e:
        episodes_for(store, "gensim", [task], 5, 1, ["top"], "successful", " pipeline.root=/my/GenSim")
    line = str(e.value)
    assert "\n" not in line and f"episodes_per_task=5 successful episodes ({task} has 4 successful of 5)" in line
    assert f"python src/collect.py pipeline=gensim pipeline.root=/my/GenSim 'tasks=[{task}]' episodes=9 " in line
    assert "demonstrations=all" in line  # 5 + 1 successes at 4/5: 7.5 episodes, and a fifth more: 9
    empty = EpisodeStore(tmp_path / "empty")  # nothing collected yet: the plain message, k + val_k episodes
    with pytest.raises(UserError) as e:
        episodes_for(empty, "gensim", [task], 5, 1, ["top"], "successful", " pipeline.root=/my/GenSim")
    assert f"({task} has 0); collect them" in str(e.value) and f"'tasks=[{task}]' episodes=6 " in str(e.value)
    assert "demonstrations=all" not in str(e.value)
    for seed in (0, 2, 4):  # now only failures are stored: no rate to size the collection by
        with h5py.File(store.path_for("gensim", task, seed), "a") as f:
            f.attrs["success"] = False
    with pytest.raises(UserError) as e:
        episodes_for(store, "gensim", [task], 2, 0, ["top"], "successful")
    assert f"({task} has 1 successful of 5)" in str(e.value)  # seed 3: success not recorded, kept
    with h5py.File(store.path_for("gensim", task, 3), "a") as f:
        f.attrs["success_known"] = True
    with pytest.raises(UserError) as e:
        episodes_for(store, "gensim", [task], 2, 0, ["top"], "successful")
    assert f"({task} has 0 successful of 5)" in str(e.value) and "episodes=<more: no stored episode of a task " \
        "succeeded>" in str(e.value) and "demonstrations=all" in str(e.value)
    with pytest.raises(UserError) as e:  # all 5 stored would still be too few for 6: no demonstrations=all offered
        episodes_for(store, "gensim", [task], 6, 0, ["top"], "successful")
    assert f"({task} has 0 successful of 5)" in str(e.value) and "demonstrations=all" not in str(e.value)
    with pytest.raises(UserError, match="demonstrations='some': must be all .* or successful"):
        episodes_for(store, "gensim", [task], 2, 0, ["top"], "some")


def test_authors_gensim_cpu_is_the_authors_abstraction_at_cpu_sizes():
    """The preset edits only sizes and budget: the action abstraction (pick/place, horizon 2, one observation, one
    executed action, unit quaternions) is authors_gensim's, read from that file, not copied."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        authors = OmegaConf.to_container(compose("generalization", ["policy=authors_gensim"]).policy)
        cpu = OmegaConf.to_container(compose("generalization", ["policy=authors_gensim_cpu"]).policy)
    assert cpu["name"] == "authors_gensim_cpu"
    changed = {k for k in authors["model"] if authors["model"][k] != cpu["model"][k]}
    assert changed == {"encoder_width", "down_dims", "inference_scheduler", "num_inference_steps"}
    assert cpu["model"]["action_space"] == "pick_place" and cpu["model"]["horizon"] == 2
    assert cpu["model"]["down_dims"] == [128, 256] and cpu["train"]["train_steps"] == 5000


def test_demonstrations_default_to_the_pipelines_own_way_and_the_command_line_wins():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        chosen = {p: compose("generalization", [f"pipeline={p}"]).demonstrations
                  for p in ("gensim", "gensim_own", "robogen", "bbsea", "metaworld")}
        overridden = compose("generalization", ["pipeline=gensim_own", "demonstrations=all"]).demonstrations
    assert chosen == {"gensim": "all", "gensim_own": "successful", "robogen": "all", "bbsea": "all",
                      "metaworld": "all"}
    assert overridden == "all"
