"""Diffusion Policy: the noise schedule and forward process against closed forms, EMA against a hand computation,
receding-horizon execution, windows, and that the policy reproduces a demonstrated trajectory."""

import math
import re

import numpy as np
import pytest
import torch

from simeval.episodes.episode import Episode
from simeval.errors import UserError
from simeval.models.diffusion_policy import (
    DiffusionPolicy,
    PolicyConfig,
    RecedingHorizonRunner,
    TrainSettings,
    make_ema,
    normalize_pose14_quaternions,
    train_policy,
)
from simeval.measures.generalization.data import PolicyDataset

TINY = dict(image_size=[32, 32], crop=28, encoder_width=8, keypoints=8, feature_dim=16, stem_pool=False, horizon=8,
            n_obs_steps=2, n_action_steps=4, down_dims=[16, 32], step_embed_dim=16, kernel_size=3, n_groups=4,
            num_train_timesteps=20, num_inference_steps=5)


@pytest.fixture(autouse=True)
def one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)  # the CI machine's cores are shared; OpenMP spin-waiting makes 2 threads slower
    yield
    torch.set_num_threads(old)


def moving_square_episode(seed=0, T=24, action_fn=None):
    """A square moves across the frame; the state is the step's phase; the action a smooth known trajectory."""
    rgb = np.zeros((T, 32, 32, 3), np.uint8)
    for t in range(T):
        x = 2 + t
        rgb[t, 10:18, x : x + 6] = (255, 200, 50)
    phase = np.linspace(0, 1, T, dtype=np.float32)
    state = np.stack([phase, phase**2, np.sin(3 * phase)], 1).astype(np.float32)
    action = action_fn(phase) if action_fn else np.stack([np.sin(2 * np.pi * phase + k) for k in range(7)], 1)
    return Episode(pipeline="p", task="t", description="", group="g", seed=seed, rgb={"top": rgb}, state=state,
                   action=action.astype(np.float32), reward=np.zeros(T, np.float32), is_first=np.arange(T) == 0,
                   is_terminal=np.arange(T) == T - 1)


def test_noise_schedule_is_the_squared_cosine_schedule_and_the_forward_process_is_ddpm():
    """abar(t) = f(t)/f(0), f(t) = cos^2((t/K + s)/(1 + s) pi/2), s = 0.008, beta capped at 0.999 (Nichol &
    Dhariwal 2021); the U-Net is fed sqrt(abar_t) x0 + sqrt(1 - abar_t) eps and trained to output eps."""
    cfg = PolicyConfig(**TINY)
    policy = DiffusionPolicy(cfg, 3, 7)
    K, s = cfg.num_train_timesteps, 0.008
    f = lambda t: math.cos((t / K + s) / (1 + s) * math.pi / 2) ** 2  # noqa: E731
    betas = [min(1 - f(i + 1) / f(i), 0.999) for i in range(K)]
    abar = np.cumprod(1 - np.array(betas))
    np.testing.assert_allclose(policy.noise_scheduler.alphas_cumprod.numpy(), abar, rtol=1e-4)  # float32 cumprod

    seen = {}

    def fake_unet(x, t, cond):
        seen["x"], seen["t"] = x.detach().clone(), t.clone()
        return torch.zeros_like(x)

    policy.unet.forward = fake_unet
    ds = PolicyDataset([moving_square_episode()], "joint", ["top"], [32, 32], cfg.horizon, cfg.n_obs_steps)
    batch = ds.sample(4, torch.Generator().manual_seed(0))
    g = torch.Generator().manual_seed(1)
    loss = policy.compute_loss(batch, generator=g)
    # replay the same draws: crop offsets (2 x 8 images x 2), then noise, then steps
    g2 = torch.Generator().manual_seed(1)
    torch.randint(0, 5, (8,), generator=g2), torch.randint(0, 5, (8,), generator=g2)
    x0 = policy.action_norm(batch["action"])
    eps = torch.randn(x0.shape, generator=g2)
    t = torch.randint(0, K, (4,), generator=g2)
    assert torch.equal(seen["t"], t)
    a = torch.as_tensor(abar, dtype=torch.float32)[t][:, None, None]
    torch.testing.assert_close(seen["x"], a.sqrt() * x0 + (1 - a).sqrt() * eps, rtol=1e-5, atol=1e-5)
    assert float(loss) == pytest.approx(float((eps**2).mean()), rel=1e-5)  # zero prediction: loss = E[eps^2]


def test_ema_follows_the_official_warmup_decay():
    """make_ema, stepped as training steps it: the decay at update n is d_n = min(1 - (1 + (n - 1))^-power,
    max_decay) (0 at the first update), and ema <- d ema + (1 - d) param, with the settings' power and max decay."""
    settings = TrainSettings()
    module = torch.nn.Linear(1, 1, bias=False)
    ema = make_ema(module, settings)
    values = [1.0, 2.0, -1.0, 4.0, 0.5, 3.0]
    hand = 0.0
    for n, v in enumerate(values, start=1):
        module.weight.data.fill_(v)
        ema.step(module.parameters())
        step = n - 1
        d = 0.0 if step <= 0 else min(1 - (1 + step) ** -settings.ema_power, settings.ema_max_decay)
        hand = d * hand + (1 - d) * v
        assert float(ema.shadow_params[0]) == pytest.approx(hand, rel=1e-6)
    assert (settings.ema_power, settings.ema_max_decay) == (0.75, 0.9999)  # the official Diffusion Policy values


def test_windows_pad_at_the_edges_and_every_action_is_executed_first_somewhere():
    # format 2: 6 actions 0..5, 7 rows; row 6 (the final observation) carries a padding copy of action 5
    acts = np.r_[np.arange(6), 5].astype(np.float32)
    ep = moving_square_episode(T=7, action_fn=lambda ph: np.repeat(acts[:, None], 7, 1))
    ds = PolicyDataset([ep], "joint", ["top"], [32, 32], horizon=4, n_obs_steps=2)
    assert len(ds) == 6 and len(ds.state) == 6  # (row t, action t) for t < 6: the final row pairs with nothing
    first = ds.window(np.array([0]))
    assert first["action"][0, :, 0].tolist() == [0, 0, 1, 2]  # start -1: the first step repeats
    assert torch.equal(first["state"][0, 0], first["state"][0, 1])
    last = ds.window(np.array([5]))
    assert last["action"][0, :, 0].tolist() == [4, 5, 5, 5]  # the last action repeats
    executed = {int(ds.window(np.array([r]))["action"][0, 1, 0]) for r in range(len(ds))}
    assert executed == set(range(6))


def test_receding_horizon_executes_actions_from_index_To_minus_1():
    cfg = PolicyConfig(**{**TINY, "horizon": 8, "n_obs_steps": 2, "n_action_steps": 3})
    policy = DiffusionPolicy(cfg, 3, 7)
    calls = []

    def fake_predict(obs, scheduler=None, steps=None, generator=None):
        calls.append(obs["state"][0, :, 0].tolist())
        base = 100 * len(calls)
        return (base + torch.arange(8.0))[None, :, None].expand(1, 8, 7)

    policy.predict_action = fake_predict
    runner = RecedingHorizonRunner(policy)
    obs = lambda i: {"rgb": {"top": np.zeros((32, 32, 3), np.uint8)}, "state": np.full(3, float(i), np.float32)}  # noqa
    got = [runner.act(obs(i))[0] for i in range(7)]
    assert got == [101, 102, 103, 201, 202, 203, 301]
    assert calls == [[0, 0], [2, 3], [5, 6]]  # first call pads with the first observation


def test_policy_reproduces_a_demonstrated_trajectory():
    """Trained on one demonstration (a 2-d circle traced while a square crosses the image), the EMA policy's
    predicted windows follow it: executed-action error far below that of predicting the mean action, with DDPM
    and with 5-step DDIM."""
    ep = moving_square_episode(action_fn=lambda ph: np.stack([np.sin(2 * np.pi * ph), np.cos(2 * np.pi * ph)], 1))
    cfg = PolicyConfig(**{**TINY, "down_dims": [32, 64], "step_embed_dim": 32})
    ds = PolicyDataset([ep], "joint", ["top"], [32, 32], cfg.horizon, cfg.n_obs_steps)
    policy, summary = train_policy(DiffusionPolicy(cfg, ds.state_dim, ds.action_dim, ds.stats()), ds,
                                   TrainSettings(train_steps=600, batch_size=16, lr=3e-3, warmup_steps=10,
                                                 checkpoint_every=10_000, log_every=100))
    assert summary["losses"][-1][1] < 0.2 * summary["losses"][0][1]
    batch = ds.window(np.arange(len(ds)))
    truth = policy.action_norm(batch["action"])
    sl = slice(cfg.n_obs_steps - 1, cfg.n_obs_steps - 1 + cfg.n_action_steps)
    baseline = float(((truth - truth.mean((0, 1)))[:, sl] ** 2).mean())
    for sampler, steps in (("ddpm", cfg.num_train_timesteps), ("ddim", cfg.num_inference_steps)):
        pred = policy.predict_action(batch, sampler, steps, torch.Generator().manual_seed(0))
        err = float(((policy.action_norm(pred) - truth)[:, sl] ** 2).mean())
        assert err < 0.1 * baseline, sampler


def test_pick_place_policy_outputs_unit_quaternions_and_uses_primitive_steps():
    T = 30
    ep = moving_square_episode(T=T)
    q = np.array([0, 0, 0.38268343, 0.92387953], np.float32)
    ep.high_level_action = np.stack([np.r_[0.5, 0.1 * i, 0.02, q, 0.4, -0.1, 0.05, q] for i in range(3)]).astype(np.float32)
    ep.high_level_step = np.array([0, 10, 20])
    ds = PolicyDataset([ep], "pick_place", ["top"], [32, 32], horizon=2, n_obs_steps=1)
    assert len(ds) == 3 and torch.equal(ds.state, torch.from_numpy(ep.state[[0, 10, 20]]))
    raw = torch.randn(5, 2, 14)
    unit = normalize_pose14_quaternions(raw)
    np.testing.assert_allclose(unit[..., 3:7].norm(dim=-1), 1, rtol=1e-6)
    np.testing.assert_allclose(unit[..., 10:14].norm(dim=-1), 1, rtol=1e-6)
    assert torch.equal(unit[..., :3], raw[..., :3])
    # the policy's own output: an untrained pick/place policy samples 14-d poses whose quaternions are unit, and
    # the same sample without the normalisation is not (so the check above is what makes them unit)
    cfg = PolicyConfig(**{**TINY, "horizon": 4, "n_obs_steps": 1, "n_action_steps": 1, "down_dims": [16, 32],
                          "normalize_quaternions": True})
    policy = DiffusionPolicy(cfg, ds.state_dim, ds.action_dim, ds.stats()).eval()
    obs = ds.window(np.arange(3))
    pred = policy.predict_action(obs, "ddim", 3, torch.Generator().manual_seed(0))
    assert pred.shape == (3, 4, 14)
    np.testing.assert_allclose(pred[..., 3:7].norm(dim=-1), 1, rtol=1e-5)
    np.testing.assert_allclose(pred[..., 10:14].norm(dim=-1), 1, rtol=1e-5)
    policy.cfg = PolicyConfig(**{**TINY, "horizon": 4, "n_obs_steps": 1, "n_action_steps": 1,
                                 "down_dims": [16, 32], "normalize_quaternions": False})
    raw_pred = policy.predict_action(obs, "ddim", 3, torch.Generator().manual_seed(0))
    assert not torch.allclose(raw_pred[..., 3:7].norm(dim=-1), torch.ones(3, 4), atol=1e-3)
    torch.testing.assert_close(normalize_pose14_quaternions(raw_pred), pred)


def test_config_mistakes_name_the_key():
    with pytest.raises(UserError, match="policy.model.horizon=2 must be a multiple of 4"):
        PolicyConfig(**{**TINY, "horizon": 2, "n_obs_steps": 1, "n_action_steps": 1, "down_dims": [8, 16, 32]})
    with pytest.raises(UserError, match="policy.model.crop=40"):
        PolicyConfig(**{**TINY, "crop": 40})
    with pytest.raises(UserError, match="unknown key"):
        PolicyConfig.from_mapping({**TINY, "hidden": 3})


def test_native_action_space_is_the_groups_own_and_a_recording_in_another_is_refused():
    from simeval.measures.generalization.run import resolve_action_space
    from simeval.sim.tasks.spec import suite_dir, load_suite, select_specs

    robogen = select_specs(load_suite(suite_dir("robogen")), None, "table_top")
    bbsea = select_specs(load_suite(suite_dir("bbsea")), None, "drawer")
    gensim = select_specs(load_suite(suite_dir("gensim")), None, "piles")
    assert [resolve_action_space("native", g) for g in (gensim, robogen, bbsea)] == ["joint", "ee_delta", "ee_pose"]
    assert resolve_action_space("pick_place", gensim) == "pick_place"
    with pytest.raises(UserError, match="different action spaces"):
        resolve_action_space("native", [robogen[0], bbsea[0]])
    ep = moving_square_episode()
    ep.action_space = {"kind": "joint_pos+suction"}  # as the store records joint-target episodes
    assert PolicyDataset([ep], "joint", ["top"], (16, 16), 4, 2).action_dim == 7
    with pytest.raises(UserError, match=r"recorded as 'joint_pos\+suction', the policy's action_space=ee_delta"):
        PolicyDataset([ep], "ee_delta", ["top"], (16, 16), 4, 2)


def test_a_trained_checkpoint_is_reused_with_another_sampler_but_not_with_other_training_settings(tmp_path):
    """The inference sampler does not shape the weights: a finished checkpoint rolled out with DDPM instead of
    DDIM is loaded (no step retrained, same weights), while a change of a training field is refused."""
    from simeval.measures.generalization.run import checkpoint_key

    ep = moving_square_episode()
    cfg = PolicyConfig(**{**TINY, "down_dims": [32, 64], "step_embed_dim": 32})
    ds = PolicyDataset([ep], "joint", ["top"], [32, 32], cfg.horizon, cfg.n_obs_steps)
    settings = TrainSettings(train_steps=3, batch_size=4, checkpoint_every=10_000, log_every=100)
    first, _ = train_policy(DiffusionPolicy(cfg, ds.state_dim, ds.action_dim, ds.stats()), ds, settings, tmp_path)

    ddpm = PolicyConfig(**{**vars(cfg), "inference_scheduler": "ddpm", "num_inference_steps": cfg.num_train_timesteps})
    # another init seed: equal weights below can only come from the checkpoint
    again, summary = train_policy(DiffusionPolicy(ddpm, ds.state_dim, ds.action_dim, ds.stats(), seed=1), ds,
                                  settings, tmp_path)
    assert summary["steps"] == settings.train_steps
    for (name, a), b in zip(first.state_dict().items(), again.state_dict().values()):
        assert torch.equal(a, b), name
    assert again.cfg.inference_scheduler == "ddpm"  # the rollouts use the sampler asked for, not the stored one

    key = lambda c: checkpoint_key([("a.h5", 1)], vars(c), vars(settings), 0)  # noqa: E731
    assert key(cfg) == key(ddpm)
    wider = PolicyConfig(**{**vars(cfg), "step_embed_dim": 64})
    assert key(wider) != key(cfg)
    with pytest.raises(UserError, match=r"last.ckpt: made with other settings or data "
                                        r"\(policy.model.step_embed_dim\); delete it or use another checkpoint_dir"):
        train_policy(DiffusionPolicy(wider, ds.state_dim, ds.action_dim, ds.stats()), ds, settings, tmp_path)


def test_a_repeated_evaluation_reuses_its_rollouts_and_says_so_and_a_corrupt_cache_is_named(tmp_path, monkeypatch,
                                                                                          caplog):
    """run_splits keeps each rollout in a cache beside the checkpoint, so a killed evaluation resumes; a rerun that
    reuses them logs how many (its numbers are not fresh rollouts), and a cache that is not one is one line naming
    the file. The rollout itself is replaced by a counter: what is tested is the cache."""
    import logging
    from types import SimpleNamespace

    from simeval.errors import UserError
    from simeval.measures.generalization import rollouts as evaluate
    from simeval.measures.generalization.run import run_splits

    calls = []

    def fake_rollout(policy, task, seeds, *, split, on_episode, **_):
        calls.append((split, task))
        for s in seeds:
            on_episode({"seed": s, "success": True, "progress": 1.0, "steps": 1})

    monkeypatch.setattr(evaluate, "rollout_task", fake_rollout)
    policy = SimpleNamespace(cfg=SimpleNamespace(inference_scheduler="ddim", num_inference_steps=16))
    plan = {"train": [("a", None)], "eval": [("a", {"colors": "eval"})]}
    cache = tmp_path / "rollouts.json"
    first = run_splits(policy, plan, [0, 1], None, cache, policy_step=100, compare_starts={})
    assert calls == [("train", "a"), ("eval", "a")] and cache.is_file()
    assert [(r["split"], r["success"]["k"], r["success"]["n"]) for r in first] == [("train", 2, 2), ("eval", 2, 2)]
    with caplog.at_level(logging.INFO, logger="simeval.measures.generalization.run"):
        again = run_splits(policy, plan, [0, 1], None, cache, policy_step=100, compare_starts={})
    assert len(calls) == 2 and again == first
    assert f"reused 4 of 4 rollouts from {cache}" in caplog.text
    run_splits(policy, plan, [0, 1], None, cache, policy_step=200, compare_starts={})  # another step: rolled out again
    assert len(calls) == 4
    # the same task name in another pipeline's environments (simeval's GenSim-style suite and GenSim's own code
    # share names; the chance baseline's cache folder is shared by every pipeline): rolled out again, then reused
    from simeval.pipelines.base import SuitePipeline
    from simeval.sim.tasks.spec import suite_dir

    suite = SuitePipeline("gensim", suite_dir("gensim")).environment_id()
    other = {**suite, "name": "gensim_own"}
    for environment in (suite, other, other):
        run_splits(policy, plan, [0, 1], None, cache, policy_step=200, environment=environment, compare_starts={})
    assert len(calls) == 8

    cache.write_text('{"cut short": ')
    with pytest.raises(UserError, match="rollouts.json: not a rollout cache .*delete it"):
        run_splits(policy, plan, [0, 1], None, cache, policy_step=100)
    cache.write_text("[]")
    with pytest.raises(UserError, match="rollouts.json: not a rollout cache \\(a JSON array, expected an object\\)"):
        run_splits(policy, plan, [0, 1], None, cache, policy_step=100)
    for text, says in [("null", "a JSON null, expected an object"),
                       ('{"[1, 2]": {"episodes": []}}', "entry '[1, 2]': not a key this product writes"),
                       ('{"k": {"episodes": null}}', "entry 'k': expected an object with its episodes, got null"),
                       ('{"k": 5}', "entry 'k': expected an object with its episodes, got number"),
                       ('{"k": {"episodes": {"0": 5}}}', "entry 'k', seed '0': expected an episode object, got number"),
                       ('{"k": {"episodes": {"0": {}}}}', "entry 'k', seed '0': its episode records seed None"),
                       ('{"k": {"episodes": {"abc": {"seed": 0}}}}', "entry 'k', seed 'abc': not a seed"),
                       ('{"k": {"episodes": {"0": {"seed": 0, "success": "yes", "progress": 1}}}}',
                        "entry 'k', seed '0': success 'yes' is not true or false"),
                       ('{"k": {"episodes": {"0": {"seed": 0, "success": true, "progress": null}}}}',
                        "entry 'k', seed '0': progress None is not a number")]:
        cache.write_text(text)  # valid JSON, not a cache: one line naming the file and the entry, not a traceback
        with pytest.raises(UserError, match=re.escape(f"rollouts.json: not a rollout cache ({says}")):
            run_splits(policy, plan, [0, 1], None, cache, policy_step=100)


def test_a_killed_evaluation_keeps_each_finished_rollout_and_more_seeds_roll_out_only_the_new_ones(tmp_path,
                                                                                                   monkeypatch):
    """Each rollout is cached as it ends: an evaluation killed in a task's third seed resumes at that seed, and a
    larger eval.seeds rolls out only the seeds not cached. Real rollouts (the chance baseline in simeval's BBSEA
    suite): the resumed and extended rows equal one uninterrupted evaluation's, episode for episode. A cache of the
    build before (one row per seed list) is read as its seeds' rollouts."""
    import json

    from simeval.measures.generalization import rollouts as ev
    from simeval.measures.generalization.run import read_rollout_cache, rollout_key, run_splits
    from simeval.measures.generalization.random_baseline import RandomActions

    task, var = "bbsea-block-in-bin", {"robot": {"home_noise": 0.3}}
    policy = RandomActions("ee_pose", cameras=["top"], image_size=(16, 16))
    plan = {"eval": [(task, var)]}
    whole = run_splits(policy, plan, [0, 1, 2, 3], 2, tmp_path / "whole.json", 0, compare_starts={})
    real_rollout = ev.rollout_task

    class Killed(Exception):
        pass

    def killed_in_third_rollout(*args, on_episode, **kwargs):
        ended = []

        def keep(episode):
            ended.append(episode["seed"])
            if len(ended) == 3:  # killed before the third rollout is kept
                raise Killed
            on_episode(episode)
        return real_rollout(*args, on_episode=keep, **kwargs)

    cache = tmp_path / "rollouts.json"
    monkeypatch.setattr(ev, "rollout_task", killed_in_third_rollout)
    with pytest.raises(Killed):
        run_splits(policy, plan, [0, 1, 2, 3], 2, cache, 0, compare_starts={})
    key = rollout_key(0, "eval", task, var, 2, ["uniform-random", 0], None)
    assert sorted(read_rollout_cache(cache)[key]["episodes"]) == ["0", "1"]

    rolled = []

    def counted(policy, task, seeds, **kwargs):
        rolled.extend(seeds)
        return real_rollout(policy, task, seeds, **kwargs)

    monkeypatch.setattr(ev, "rollout_task", counted)
    (resumed,) = run_splits(policy, plan, [0, 1, 2, 3], 2, cache, 0, compare_starts={})
    assert rolled == [2, 3] and resumed == whole[0]
    (more,) = run_splits(policy, plan, [0, 1, 2, 3, 4, 5], 2, cache, 0, compare_starts={})
    assert rolled == [2, 3, 4, 5] and more["episodes"][:4] == whole[0]["episodes"]
    (fewer,) = run_splits(policy, plan, [1, 2], 2, cache, 0, compare_starts={})
    assert rolled == [2, 3, 4, 5] and fewer["episodes"] == whole[0]["episodes"][1:3]

    # the build before kept one row per seed list: its seeds are reused, the rest rolled out, the file rewritten
    old_key = json.dumps([0, "eval", task, [0, 1], var, 2, ["uniform-random", 0], {}], sort_keys=True)
    old = tmp_path / "old.json"
    old.write_text(json.dumps({old_key: {"task": task, "split": "eval",
                                         **ev.episodes_summary(whole[0]["episodes"][:2])}}))
    (upgraded,) = run_splits(policy, plan, [0, 1, 2, 3], 2, old, 0, compare_starts={})
    assert rolled == [2, 3, 4, 5, 2, 3] and upgraded == whole[0]
    assert list(json.loads(old.read_text())) == [key]


def test_an_eval_variation_that_changes_no_scene_is_not_rolled_out_again(tmp_path):
    """The eval split reads the policy on scenes its variation changed. A seed whose first observation is the train
    rollout's (a variation that varies nothing) is recorded as unvaried and not rolled out; one that moves the
    robot's start is rolled out. The train starts come from the train rows, or, for train rows cached before they
    recorded them, from resetting the train environment."""
    import json

    from simeval.measures.generalization import rollouts as ev
    from simeval.measures.generalization.run import run_splits
    from simeval.measures.generalization.random_baseline import RandomActions
    from simeval.sim import make_env

    task, seeds = "bbsea-block-in-bin", [0, 1]
    env = make_env(task, action_space="ee_pose", image_size=(16, 16), cameras=("top",))
    try:  # the digest against the observation itself: equal for the same seed, not for one pixel changed
        obs = env.reset(seed=0)[0]
        assert ev.observation_digest(env.reset(seed=0)[0]) == ev.observation_digest(obs)
        changed = {"rgb": {"top": obs["rgb"]["top"].copy()}, "state": obs["state"]}
        changed["rgb"]["top"][3, 5, 1] ^= 1
        assert ev.observation_digest(changed) != ev.observation_digest(obs)
    finally:
        env.close()
    policy = RandomActions("ee_pose", cameras=["top"], image_size=(16, 16))
    nothing, robot = {}, {"robot": {"home_noise": 0.3}}
    cache = tmp_path / "rollouts.json"
    run_splits(policy, {"train": [(task, nothing)]}, seeds, 2, cache, 0)
    stored = json.loads(cache.read_text())  # as a cache written before rollouts recorded their start
    for row in stored.values():
        for episode in row["episodes"].values():
            del episode["start"]
    cache.write_text(json.dumps(stored))
    plan = {"train": [(task, nothing)], "eval": [(task, nothing), (task, robot)]}
    train, same, moved = run_splits(policy, plan, seeds, 2, cache, 0)
    starts = [ev.observation_digest(make_env(task, action_space="ee_pose", image_size=(16, 16),
                                             cameras=("top",)).reset(seed=s)[0]) for s in seeds]
    assert same["episodes"] == [{"seed": s, "start": d, "unvaried": True} for s, d in zip(seeds, starts)]
    assert same["success"]["n"] == 0 and same["mean_progress"] is None and same["unvaried"] == 2
    assert [e["start"] != d and e["steps"] >= 1 for e, d in zip(moved["episodes"], starts)] == [True, True]
    assert moved["unvaried"] == 0 and moved["success"]["n"] == 2
    summary = ev.summarize([train, same, moved])["eval"]
    assert (summary["success"]["n"], summary["unvaried"], summary["tasks"]) == (2, 2, 2)
    assert summary["mean_progress"] == np.mean([e["progress"] for e in moved["episodes"]])
    fresh = ev.rollout_task(policy, task, seeds, max_steps=2)  # a train rollout records its start
    assert [e["start"] for e in fresh["episodes"]] == starts and fresh["unvaried"] == 0

    # an eval row cached before its seeds were compared (rolled out in full, no starts), read again with the train
    # split: its seeds are compared then, the cache corrected; and without the train split in the run
    old = ev.rollout_task(policy, task, seeds, split="eval", variation=nothing, max_steps=2)
    for episode in old["episodes"]:
        del episode["start"]
    old.pop("unvaried")
    for plan, compare in (({"train": [(task, nothing)], "eval": [(task, nothing)]}, None),
                          ({"eval": [(task, nothing)]}, {task: nothing})):
        cache = tmp_path / f"old_{len(plan)}.json"
        key = json.dumps([0, "eval", task, seeds, nothing, 2, ["uniform-random", 0], {}], sort_keys=True)
        cache.write_text(json.dumps({key: old}))
        *_, marked = run_splits(policy, plan, seeds, 2, cache, 0, compare_starts=compare)
        assert marked["episodes"] == same["episodes"] and marked["success"]["n"] == 0 and marked["unvaried"] == 2
        assert cached_unvaried(cache) == 2
    # compare_starts={} compares nothing: what a variation with a knob the first observation cannot show gets; a
    # cached row with seeds left out by a comparison (an earlier build's) is rolled out again
    (kept,) = run_splits(policy, {"eval": [(task, nothing)]}, seeds, 2, cache, 0, compare_starts={})
    assert kept["unvaried"] == 0 and kept["success"]["n"] == 2
    assert cached_unvaried(cache) == 0


def cached_unvaried(cache) -> int:
    """How many rollouts the cache file keeps as unvaried."""
    import json

    return sum(bool(e.get("unvaried")) for row in json.loads(cache.read_text()).values()
               for e in row["episodes"].values())


def test_a_variation_of_friction_is_one_a_first_observation_cannot_show():
    """Friction changes no pixel and no joint at the start (spec.py draws it last for that reason): the eval split
    must roll such a variation out on every seed, not leave it out as unvaried."""
    from simeval.pipelines.base import SuitePipeline
    from simeval.sim.tasks.spec import suite_dir

    suite = SuitePipeline("bbsea", suite_dir("bbsea"))
    assert suite.unseen_knobs({"block": {"friction": [0.05, 0.1], "colors": ["red"]}, "robot": {"home_noise": 0.1}}) \
        == ["block.friction"]
    assert suite.unseen_knobs({"robot": {"home_noise": 0.1}}) == [] and suite.unseen_knobs({}) == []
