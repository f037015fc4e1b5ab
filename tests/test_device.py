"""The `device` option (simeval.runtime.device): how a value resolves, its one-line errors (also through both
entrypoints), device=cpu giving exactly the numbers of a run where every tensor stays on the CPU, checkpoints that
hold CPU tensors and are not keyed by the device, and no CPU tensor left in the models' computation when they sit on
another device (PyTorch's `meta` device stands in for a GPU: mixing it with a CPU tensor fails as CUDA does). A GPU
is used only by the test marked `gpu`, skipped where torch sees none."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from simeval.episodes.dataset import WindowDataset, WindowSpec
from simeval.errors import UserError
from simeval.runtime.device import resolve_device, to_cpu, to_device
from simeval.models.diffusion_policy import (DiffusionPolicy, TrainSettings, load_checkpoint,
                                             make_scheduler, policy_from_checkpoint, train_policy)
from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate, load_model
from simeval.measures.generalization.data import PolicyDataset
from simeval.measures.dynamics_diversity.controls.synthetic import make_group
from simeval.models.world_model_training import TrainConfig, step_generator, train
from simeval.models.world_model import WorldModel, WorldModelConfig, straight_through_sample
from helpers import policy_config, square_episode

ROOT = Path(__file__).resolve().parents[1]
CUDA = torch.cuda.is_available()
HERE = "cuda" if CUDA else "cpu"  # what auto means on this machine
# device=cpu spelled every way the library accepts; None and "auto" mean cpu only where torch sees no GPU
CPU_SPELLINGS = ["cpu", torch.device("cpu")] + ([] if CUDA else [None, "auto"])


@pytest.fixture(autouse=True)
def one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)  # the machine's cores are shared with long jobs
    yield
    torch.set_num_threads(old)


def wm_config() -> WorldModelConfig:
    return WorldModelConfig.from_dict(yaml.safe_load((ROOT / "conf" / "world_model" / "tiny.yaml").read_text())["model"])


def all_tensors(obj):
    if isinstance(obj, torch.Tensor):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from all_tensors(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from all_tensors(v)


def assert_same_weights(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k].cpu(), b[k].cpu(), rtol=0, atol=0, msg=k)


# --- resolving the option ------------------------------------------------------------------------------------------
def test_auto_is_cuda_when_torch_sees_a_gpu_else_cpu():
    assert resolve_device("auto").type == resolve_device(None).type == HERE
    assert resolve_device("cpu") == resolve_device(torch.device("cpu")) == torch.device("cpu")


@pytest.mark.parametrize("value", ["gpu", "CUDA", "cuda:x", "cuda:-1", "cpu:0", "", 0])
def test_a_bad_value_is_one_line_naming_the_key_and_the_valid_values(value):
    with pytest.raises(UserError) as e:
        resolve_device(value)
    assert str(e.value).startswith(f"device={value!r}: expected one of auto, cpu, cuda, cuda:N")
    assert "\n" not in str(e.value)


def test_cuda_without_cuda_is_one_line_saying_what_is_available(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    for value in ("cuda", "cuda:1"):
        with pytest.raises(UserError) as e:
            resolve_device(value, key="world_model.device")
        msg = str(e.value)
        assert msg.startswith(f"world_model.device={value!r}: CUDA is not available here")
        assert msg.endswith("available: auto (= cpu here), cpu") and "\n" not in msg


def test_a_gpu_index_the_machine_lacks_lists_the_ones_it_has(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
    assert resolve_device("cuda") == resolve_device("auto") == torch.device("cuda", 0)  # recorded with its index
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    with pytest.raises(UserError, match=r"^device='cuda:2': this machine has 2 CUDA device\(s\); available: auto, "
                                        r"cpu, cuda:0, cuda:1$"):
        resolve_device("cuda:2")


@pytest.mark.parametrize("entrypoint", ["diversity", "generalization"])
@pytest.mark.parametrize("value", ["gpu", pytest.param("cuda", marks=pytest.mark.skipif(CUDA, reason="has CUDA"))])
def test_the_entrypoints_stop_on_a_bad_device_with_one_line_and_exit_2(entrypoint, value, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}
    r = subprocess.run([sys.executable, str(ROOT / "src" / f"{entrypoint}.py"), f"device={value}",
                        f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.startswith(f"error: device='{value}': ") and r.stderr.count("\n") == 1
    assert "Traceback" not in r.stderr
    assert ("expected one of auto, cpu, cuda, cuda:N" if value == "gpu" else "available: auto (= cpu here), cpu") \
        in r.stderr


def test_to_cpu_keeps_structure_and_state_dict_metadata_and_does_not_copy_cpu_tensors():
    sd = torch.nn.Linear(2, 3).state_dict()
    out = to_cpu({"model": sd, "pair": (sd["weight"], 1), "list": [sd["bias"]], "step": 3})
    assert type(out["model"]) is OrderedDict and out["model"]._metadata == sd._metadata
    assert out["pair"][0] is sd["weight"] and out["pair"][1] == 1 and out["list"][0] is sd["bias"]
    assert out["step"] == 3
    batch = {"rgb": {"top": torch.zeros(1)}, "state": torch.ones(1), "name": "x"}
    moved = to_device(batch, torch.device("cpu"))
    assert moved["rgb"]["top"] is batch["rgb"]["top"] and moved["name"] == "x"


# --- device=cpu is the CPU-only path, bit for bit -------------------------------------------------------------------
def _fit(device, checkpoint_dir=None):
    return fit_and_evaluate(make_group("diverse", 2, 3, 10, 16, seed=0), 2,
                            Training(wm_config(), TrainConfig(epochs=2, batch_size=4, lr=1e-3, checkpoint_every=3),
                                     WindowSpec(length=6, stride=3)),
                            Evaluation(episodes=(0, 3), heldout_episodes=None),
                            Execution(checkpoint_dir=checkpoint_dir, progress=False, device=device))


def test_world_model_results_are_the_same_for_every_spelling_of_cpu():
    runs = [_fit(d) for d in CPU_SPELLINGS]
    for r in runs[1:]:
        assert r["eval"] == runs[0]["eval"]  # every error, open-loop error and per-task number, exactly
        assert r["train"]["last"] == runs[0]["train"]["last"]
    assert {r["train"]["device"] for r in runs} == {"cpu"}


def test_world_model_training_on_cpu_is_a_plain_cpu_training_loop_bit_for_bit():
    """train(device="cpu") against the loop it implements, written with CPU tensors only: the same windows, the same
    step generators, Adam and gradient clipping, and no device handling anywhere."""
    cfg = TrainConfig(epochs=2, batch_size=4, lr=1e-3, seed=3)
    ds = WindowDataset(make_group("shared", 2, 3, 10, 16, seed=0), WindowSpec(length=6, stride=3, random_offset=True),
                       image_size=16, seed=cfg.seed)
    ds.stats = ds.fit_stats()
    models = []
    for _ in range(2):
        torch.manual_seed(cfg.seed)
        models.append(WorldModel(wm_config(), len(ds.stats.state_mean), len(ds.stats.action_mean)))
    summary = train(models[0], ds, cfg, progress=False, device="cpu")

    ref = models[1]
    opt = torch.optim.Adam(ref.parameters(), lr=cfg.lr, eps=cfg.eps)
    step = 0
    for epoch in range(cfg.epochs):
        order = np.random.default_rng([cfg.seed, epoch, 11]).permutation(len(ds.windows(epoch)))
        windows = ds.windows(epoch)[order]
        for i in range(0, len(windows), cfg.batch_size):
            items = [ds[(int(e), int(s))] for e, s in windows[i : i + cfg.batch_size]]
            batch = {k: torch.from_numpy(np.stack([it[k] for it in items])) for k in items[0]}
            loss, last = ref.loss(batch, generator=step_generator(cfg.seed, step))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(ref.parameters(), cfg.clip)
            opt.step()
            step += 1
    assert summary["steps"] == step and summary["last"]["loss"] == last["loss"]
    assert_same_weights(models[0].state_dict(), ref.state_dict())


def _train_policy(device, ckpt_dir=None, steps=6):
    ds = PolicyDataset([square_episode()], "joint", ["top"], [32, 32], 8, 2)
    fresh = DiffusionPolicy(policy_config(), ds.state_dim, ds.action_dim, ds.stats(), seed=0)
    policy, summary = train_policy(fresh, ds, TrainSettings(train_steps=steps, batch_size=8, warmup_steps=2,
                                                            checkpoint_every=3, log_every=2), ckpt_dir, device=device)
    return policy, summary, ds


def test_policy_training_and_sampling_are_the_same_for_every_spelling_of_cpu():
    runs = [_train_policy(d) for d in CPU_SPELLINGS]
    obs = runs[0][2].window(np.arange(5))
    samples = [p.predict_action(obs, "ddpm", 20, torch.Generator().manual_seed(7)) for p, _, _ in runs]
    for (p, s, _), a in zip(runs[1:], samples[1:]):
        assert s["losses"] == runs[0][1]["losses"] and s["device"] == "cpu"
        assert_same_weights(p.state_dict(), runs[0][0].state_dict())
        assert torch.equal(a, samples[0])


def test_policy_sampling_on_cpu_is_the_plain_cpu_reverse_diffusion_bit_for_bit():
    """predict_action(device cpu) against DDPM's reverse steps written with CPU tensors only: the initial noise and
    every step's noise drawn from the same CPU generator in the same order."""
    policy, _, ds = _train_policy("cpu")
    obs = ds.window(np.arange(5))
    got = policy.predict_action(obs, "ddpm", 20, torch.Generator().manual_seed(7))

    gen, cfg = torch.Generator().manual_seed(7), policy.cfg
    sched = make_scheduler("ddpm", cfg.num_train_timesteps, cfg.beta_schedule)
    sched.set_timesteps(cfg.num_train_timesteps)
    with torch.no_grad():
        cond = policy.encode_obs(obs, train=False)
        x = torch.randn((5, cfg.horizon, policy.action_dim), generator=gen)
        for t in sched.timesteps:
            x = sched.step(policy.unet(x, t, cond), t, x, generator=gen).prev_sample
        want = policy.action_norm.inverse(x)
    assert got.device.type == "cpu" and torch.equal(got, want)


# --- checkpoints: CPU tensors, not keyed by the device --------------------------------------------------------------
def test_world_model_checkpoint_holds_cpu_tensors_and_is_found_again_whatever_the_device(tmp_path):
    first = _fit("cpu", tmp_path)
    (path,) = tmp_path.glob("world_model-*.pt")
    assert first["checkpoint"] == str(path)
    for ck in (torch.load(path, map_location="cpu", weights_only=False), torch.load(path, weights_only=False)):
        assert ck["finished"] and all(t.device.type == "cpu" for t in all_tensors(ck))
        assert "device" not in ck["meta"] and "device" not in ck["meta"]["train"]
    model, _ = load_model(path, device="cpu")
    assert_same_weights(model.state_dict(), torch.load(path, weights_only=False)["model"])
    # the same call with the default device: the finished checkpoint is found (the same file) and only evaluated
    again = _fit(None, tmp_path)
    assert list(tmp_path.glob("world_model-*.pt")) == [path] and again["checkpoint"] == str(path)
    assert again["train"]["steps"] == first["train"]["steps"]
    if not CUDA:
        assert again["eval"] == first["eval"]


def test_policy_training_without_a_progress_bar_logs_its_pace_each_tenth(tmp_path, caplog):
    """progress=false (SLURM logs): a line per tenth of the steps with the loss logged last, the pace and the time
    left; a finished training found again is reused and logs none."""
    import logging

    with caplog.at_level(logging.INFO, logger="simeval.models.diffusion_policy"):
        _train_policy("cpu", tmp_path, steps=10)
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("policy training: step")]
    assert [int(m.split()[3].split("/")[0]) for m in lines] == list(range(1, 11))
    assert lines[0].startswith("policy training: step 1/10, loss not logged yet, ") and lines[0].endswith(" left")
    assert lines[1].startswith("policy training: step 2/10, loss ")  # log_every=2: its first mean
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="simeval.models.diffusion_policy"):
        _train_policy("cpu", tmp_path, steps=10)  # finished: reused, nothing to train and no pace line
    assert not [r for r in caplog.records if r.getMessage().startswith("policy training: step")]


def test_policy_checkpoint_holds_cpu_tensors_and_loads_onto_a_device(tmp_path):
    policy, summary, _ = _train_policy("cpu", tmp_path)
    path = tmp_path / "last.ckpt"
    raw = torch.load(path, weights_only=False)  # no map_location: it must not name a GPU
    assert raw["step"] == summary["steps"] and all(t.device.type == "cpu" for t in all_tensors(raw))
    assert "device" not in raw["train"]
    loaded = policy_from_checkpoint(load_checkpoint(path), device="cpu")
    assert_same_weights(loaded.state_dict(), policy.state_dict())
    # a rerun with the default device finds the finished checkpoint (the key has no device) and trains no more
    again, summary2, _ = _train_policy(None, tmp_path)
    assert summary2["steps"] == summary["steps"] and summary2["losses"] == summary["losses"]


# --- nothing left on the CPU when the model sits elsewhere (meta stands in for a GPU) --------------------------------
def test_policy_loss_and_both_samplers_keep_to_the_policys_device():
    meta = torch.device("meta")  # shapes without values; a CPU tensor mixed in fails like one mixed into CUDA work
    policy = DiffusionPolicy(policy_config(), 2, 2, seed=0).to(meta)
    batch = {"rgb": {"top": torch.zeros(4, 2, 32, 32, 3, dtype=torch.uint8)}, "state": torch.zeros(4, 2, 2),
             "action": torch.zeros(4, 8, 2)}  # on the CPU, as a dataset gives them
    gen = torch.Generator().manual_seed(0)  # the seeded CPU generator the training and the runner use
    assert policy.compute_loss(batch, generator=gen).device == meta
    for sampler, steps in (("ddpm", 20), ("ddim", 5)):
        assert policy.predict_action(batch, sampler, steps, gen).shape == (4, 8, 2)


def test_world_model_loss_and_open_loop_keep_to_the_models_device(monkeypatch):
    meta = torch.device("meta")
    # the RSSM reads which steps reset (is_first.any(0).tolist()), which a meta tensor cannot answer: every step
    plain = torch.Tensor.tolist
    monkeypatch.setattr(torch.Tensor, "tolist", lambda self: [True] * len(self) if self.is_meta else plain(self))
    model = WorldModel(wm_config(), 3, 2).to(meta)
    is_first = torch.zeros(2, 5, dtype=torch.bool)
    is_first[:, 0] = True
    batch = to_device({"image": torch.zeros(2, 5, 16, 16, 3, dtype=torch.uint8), "state": torch.zeros(2, 5, 3),
                       "prev_action": torch.zeros(2, 5, 2), "is_first": is_first,
                       "mask": torch.ones(2, 5, dtype=torch.bool)}, meta)
    gen = torch.Generator().manual_seed(0)
    assert {v.device for v in model.step_errors(batch, generator=gen).values()} == {meta}
    assert {v.device for v in model.open_loop_errors(batch, 2, generator=gen).values()} == {meta}


def test_latent_samples_are_cpu_generator_draws_whatever_the_device():
    """straight_through_sample draws its uniforms from the CPU generator (then moves them): the Gumbel-max sample of
    a seed is the one computed here from torch.rand on the CPU, so every device gets it."""
    logp = torch.log_softmax(torch.randn(3, 4, 5, generator=torch.Generator().manual_seed(1)), -1)
    sample = straight_through_sample(logp, torch.Generator().manual_seed(5))
    u = torch.rand(logp.shape, generator=torch.Generator().manual_seed(5))
    # the forward value is one-hot up to rounding (one_hot + p - p): compare the chosen classes
    assert torch.equal(sample.argmax(-1), (logp - torch.log(-torch.log(u))).argmax(-1))


# --- on a GPU (skipped without one) -------------------------------------------------------------------------------
@pytest.mark.gpu
@pytest.mark.skipif(not CUDA, reason="torch sees no GPU")
def test_tiny_training_on_cuda_matches_cpu_and_its_checkpoints_load_on_cpu(tmp_path):
    logp = torch.log_softmax(torch.randn(3, 4, 5), -1)
    on_gpu = straight_through_sample(logp.cuda(), torch.Generator().manual_seed(5)).cpu()
    on_cpu = straight_through_sample(logp, torch.Generator().manual_seed(5))
    assert torch.equal(on_gpu.argmax(-1), on_cpu.argmax(-1))  # the same classes drawn
    torch.testing.assert_close(on_gpu, on_cpu)  # one_hot + p - p: equal up to the devices' rounding of exp

    gpu, cpu = _fit("cuda", tmp_path / "gpu"), _fit("cpu")
    assert gpu["train"]["device"].startswith("cuda")
    assert gpu["eval"]["image_error"] == pytest.approx(cpu["eval"]["image_error"], rel=1e-3)
    ck = torch.load(gpu["checkpoint"], weights_only=False)
    assert all(t.device.type == "cpu" for t in all_tensors(ck))
    again = _fit("cpu", tmp_path / "gpu")  # the GPU's checkpoint, evaluated on the CPU
    assert again["checkpoint"] == gpu["checkpoint"] and again["train"]["device"] == "cpu"
    assert again["eval"]["image_error"] == pytest.approx(gpu["eval"]["image_error"], rel=1e-4)

    policy, summary, ds = _train_policy("cuda", tmp_path / "policy")
    assert next(policy.parameters()).is_cuda and summary["device"].startswith("cuda")
    on_cpu = policy_from_checkpoint(load_checkpoint(tmp_path / "policy" / "last.ckpt"), device="cpu")
    obs = ds.window(np.arange(5))
    a = policy.predict_action(obs, "ddim", 5, torch.Generator().manual_seed(7)).cpu()
    b = on_cpu.predict_action(obs, "ddim", 5, torch.Generator().manual_seed(7))
    torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-3)
