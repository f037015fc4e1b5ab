"""The world model (simeval.models.world_model) against hand computations and torch.distributions, the presets'
sizes, seeded evaluation, and resuming a run killed with SIGKILL."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
import yaml

from simeval.models.world_model import (WorldModel, WorldModelConfig, categorical_kl, straight_through_sample, symlog,
                                        unimix_logits)
from simeval.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
torch.set_num_threads(1)


def preset(name: str) -> WorldModelConfig:
    return WorldModelConfig.from_dict(yaml.safe_load((ROOT / "conf" / "world_model" / f"{name}.yaml").read_text())["model"])


def test_unimix_by_hand():
    logits = torch.log(torch.tensor([0.7, 0.2, 0.1, 0.0 + 1e-12]))
    p = unimix_logits(logits, 0.01).exp()
    np.testing.assert_allclose(p.numpy(), 0.99 * np.array([0.7, 0.2, 0.1, 0.0]) + 0.01 / 4, atol=1e-6)
    assert p.min() >= 0.0025 - 1e-7


def test_kl_matches_torch_distributions_summed_over_latents():
    g = torch.Generator().manual_seed(0)
    lp = torch.log_softmax(torch.randn(3, 5, 7, generator=g), -1)
    lq = torch.log_softmax(torch.randn(3, 5, 7, generator=g), -1)
    ref = torch.distributions.kl_divergence(torch.distributions.Categorical(logits=lp),
                                            torch.distributions.Categorical(logits=lq)).sum(-1)
    torch.testing.assert_close(categorical_kl(lp, lq), ref)
    assert torch.all(categorical_kl(lp, lp).abs() < 1e-6)


def test_straight_through_sample_is_one_hot_with_probability_gradients():
    logits = torch.tensor([[0.3, -1.0, 2.0]], requires_grad=True)
    logp = torch.log_softmax(logits, -1)
    z = straight_through_sample(logp, torch.Generator().manual_seed(1))
    assert sorted(z.detach().flatten().tolist()) == [0.0, 0.0, 1.0]
    (z * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    p = logp.exp().detach()[0]
    w = torch.tensor([1.0, 2.0, 3.0])  # d/dlogits of sum(w * softmax) = p * (w - p.w)
    torch.testing.assert_close(logits.grad[0], p * (w - (p * w).sum()))


def test_sampling_frequencies_match_the_probabilities():
    logp = torch.log(torch.tensor([0.6, 0.3, 0.1])).expand(20000, 3)
    z = straight_through_sample(logp, torch.Generator().manual_seed(0)).detach()
    np.testing.assert_allclose(z.mean(0).numpy(), [0.6, 0.3, 0.1], atol=0.015)


def test_symlog_by_hand():
    x = torch.tensor([-math.e + 1, 0.0, 3.0])
    torch.testing.assert_close(symlog(x), torch.tensor([-1.0, 0.0, math.log(4.0)]))


def test_paper_preset_size_and_cpu_preset(capsys):
    paper = WorldModel(preset("paper"), state_dim=7, action_dim=7)
    cpu = WorldModel(preset("cpu"), state_dim=7, action_dim=7)
    n_paper, n_cpu = paper.n_parameters(), cpu.n_parameters()
    with capsys.disabled():
        print(f"\nworld model parameters: paper {n_paper / 1e6:.1f}M, cpu {n_cpu / 1e6:.2f}M")
    assert 50e6 < n_paper < 56e6  # the brief's ~53M for the authors' settings
    # the flattened feature of the paper preset is 16x16 (3 stride-2 stages from 128) with 128 channels
    assert paper.encoder.out_dim == 16 * 16 * 128 and cpu.encoder.out_dim == 4 * 4 * 128


def batch(b=2, t=6, size=16, d=3, a=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    is_first = torch.zeros(b, t, dtype=torch.bool)
    is_first[:, 0] = True
    return {"image": torch.randint(0, 256, (b, t, size, size, 3), generator=g, dtype=torch.uint8),
            "state": torch.randn(b, t, d, generator=g), "prev_action": torch.randn(b, t, a, generator=g),
            "is_first": is_first, "mask": torch.ones(b, t, dtype=torch.bool)}


def tiny() -> WorldModel:
    torch.manual_seed(0)
    return WorldModel(preset("tiny"), state_dim=3, action_dim=2)


def test_loss_combines_terms_with_the_dreamer_weights():
    m, x = tiny(), batch()
    e = m.step_errors(x, torch.Generator().manual_seed(0))
    loss, met = m.loss(x, torch.Generator().manual_seed(0))
    expected = (e["image_se"] + e["state_se"] + 0.5 * e["kl_dyn"].clamp_min(1.0) + 0.1 * e["kl_rep"].clamp_min(1.0)).mean()
    torch.testing.assert_close(loss, expected)
    # the image term is a sum over 16 x 16 x 3 values in [0, 1]
    assert 0 < met["image_se"] <= 16 * 16 * 3


def test_is_first_resets_the_state_mid_window():
    """A window whose step 3 is an episode start gives, from step 3 on, what a window starting there gives."""
    m, x = tiny(), batch(t=6)
    x["is_first"][:, 3] = True
    gen = lambda: torch.Generator().manual_seed(5)  # noqa: E731
    torch.manual_seed(0)
    full = m.step_errors(x, gen())
    tail = {k: v[:, 3:] for k, v in x.items()}
    # same latent noise for the tail steps: draw (and drop) the head's samples first
    g = gen()
    for _ in range(3):
        for _ in range(2):  # prior and posterior sample per step
            torch.rand((2, m.cfg.stoch, m.cfg.classes), generator=g)
    part = m.step_errors(tail, g)
    torch.testing.assert_close(full["image_se"][:, 3:], part["image_se"])


def test_the_split_posterior_layer_equals_the_layer_on_the_concatenated_input():
    """observe() applies the posterior MLP's first layer as W_d @ deter + W_e @ embed, with W_e @ embed for the
    whole window in one matmul (RSSM.split_obs_layer, for speed). Reference: the layer itself on cat(deter, embed),
    step by step, with the same latent noise; values and the gradients of every parameter and of the embeddings."""
    m, x = tiny(), batch(t=6)
    rssm = m.rssm
    torch.manual_seed(3)
    embed = torch.randn(2, 6, rssm.obs_out[0].in_features - rssm.cfg.deter, requires_grad=True)
    x["is_first"][:, 3] = True  # a reset mid-window too

    def reference():
        g, state, logps = torch.Generator().manual_seed(7), rssm.initial(2), []
        for i in range(6):
            first = x["is_first"][:, i].float()[:, None]
            init = rssm.initial(2)
            prev = {"deter": state["deter"] * (1 - first) + init["deter"] * first,
                    "stoch": state["stoch"] * (1 - first[..., None]) + init["stoch"] * first[..., None]}
            prior = rssm.img_step(prev, x["prev_action"][:, i] * (1 - first), g)
            logp = rssm._logp(rssm.post_head, rssm.obs_out(torch.cat([prior["deter"], embed[:, i]], -1)))
            state = {"deter": prior["deter"], "stoch": straight_through_sample(logp, g), "logp": logp}
            logps.append(logp)
        return torch.stack(logps, 1)

    def grads(out):
        rssm.zero_grad(set_to_none=True)
        embed.grad = None
        (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
        return [p.grad.clone() for p in rssm.parameters() if p.grad is not None] + [embed.grad.clone()]

    want = reference()
    got = rssm.observe(embed, x["prev_action"], x["is_first"], generator=torch.Generator().manual_seed(7))[0]["logp"]
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
    for a, b in zip(grads(got), grads(reference()), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_one_draw_per_window_gives_the_uniforms_of_one_draw_per_sample():
    """RSSM.uniforms draws a window's latent noise in one torch.rand call (one host-to-device copy on a GPU). The
    reference: one torch.rand call per sample, in the order the steps consume them (prior, then posterior)."""
    rssm = tiny().rssm
    for t, draws, b in ((6, 2, 2), (40, 2, 8), (3, 1, 5)):
        g = torch.Generator().manual_seed(11)
        one_call = rssm.uniforms(t, draws, b, g)
        g = torch.Generator().manual_seed(11)
        shape = (b, rssm.cfg.stoch, rssm.cfg.classes)
        per_sample = torch.stack([torch.stack([torch.rand(shape, generator=g) for _ in range(draws)])
                                  for _ in range(t)])
        assert torch.equal(one_call, per_sample)


def test_observe_samples_what_step_by_step_draws_sample_bit_for_bit():
    """observe() (noise drawn per window, resets read once) against obs_step called step by step with the generator
    (noise drawn per sample, the reset asked of each step's tensor), a mid-window reset included: the same samples,
    log-probabilities and states exactly, and so the same loss as the code before the window-wise draws."""
    m, x = tiny(), batch(t=7)
    x["is_first"][0, 4] = True
    rssm = m.rssm
    embed = m.embed(m._images(x), x["state"])
    got = rssm.observe(embed, x["prev_action"], x["is_first"], generator=torch.Generator().manual_seed(5))[0]
    g, state, posts = torch.Generator().manual_seed(5), rssm.initial(2), []
    deter_weight, embed_weight = rssm.split_obs_layer()
    shares = F.linear(embed, embed_weight)  # as observe() computes them (a per-step matmul rounds otherwise)
    for i in range(7):
        state, _ = rssm.obs_step(state, x["prev_action"][:, i], shares[:, i], x["is_first"][:, i], deter_weight,
                                 generator=g)
        posts.append(state)
    for k in ("stoch", "logp", "deter"):
        assert torch.equal(got[k], torch.stack([p[k] for p in posts], 1)), k


def test_compiled_steps_train_to_the_eager_numbers_in_the_same_checkpoint(tmp_path):
    """compile=True (WorldModel.compile_steps, torch.compile) against eager training of the same run: the compiler
    really ran (dynamo captured frames), the evaluation agrees to float32 rounding, and the checkpoint is the same
    file (compiling is not part of its key) with the model's own state_dict keys, so either kind of run resumes it."""
    from torch._dynamo.utils import counters

    from simeval.episodes.dataset import WindowSpec
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group
    from simeval.models.world_model_training import TrainConfig

    def fit(compile_steps: bool, folder):
        return fit_and_evaluate(make_group("diverse", 2, 3, 10, 16, seed=0), 2,
                                Training(preset("tiny"), TrainConfig(epochs=2, batch_size=4, lr=1e-3),
                                         WindowSpec(length=6, stride=3)),
                                Evaluation(episodes=(0, 3), heldout_episodes=None),
                                Execution(checkpoint_dir=folder, progress=False, device="cpu", compile=compile_steps))

    counters.clear()
    compiled = fit(True, tmp_path / "compiled")
    assert counters["frames"]["ok"] > 0 and compiled["train"]["compile"] is True
    eager = fit(False, tmp_path / "eager")
    assert eager["train"]["compile"] is False
    assert compiled["eval"]["image_error"] == pytest.approx(eager["eval"]["image_error"], rel=1e-4)
    assert compiled["eval"]["open_loop_image_error"] == pytest.approx(eager["eval"]["open_loop_image_error"], rel=1e-4)
    assert Path(compiled["checkpoint"]).name == Path(eager["checkpoint"]).name
    saved = torch.load(compiled["checkpoint"], weights_only=False)["model"]
    assert sorted(saved) == sorted(tiny().state_dict())
    # an eager process finds the compiled training finished: its result says how the training ran, not this process
    again = fit(False, tmp_path / "compiled")
    steps = compiled["train"]["steps"]
    assert again["train"]["compile"] is False and again["train"]["steps"] == steps
    assert again["train"]["segments"] == compiled["train"]["segments"] == [
        {"steps": [0, steps], "device": "cpu", "compile": True, "capture": False}]
    assert again["eval"]["image_error"] == pytest.approx(compiled["eval"]["image_error"], rel=1e-5)


def test_mask_excludes_padded_steps():
    m, x = tiny(), batch()
    x["mask"][:, 4:] = False
    _, met = m.loss(x, torch.Generator().manual_seed(0))
    e = m.step_errors(x, torch.Generator().manual_seed(0))
    assert met["image_se"] == pytest.approx(float(e["image_se"][:, :4].detach().mean()), rel=1e-5)


def test_bad_config_is_a_user_error_naming_the_key():
    with pytest.raises(UserError, match="world_model.model.image_size=48"):
        WorldModelConfig(image_size=48, minres=4)
    with pytest.raises(UserError, match="unknown key"):
        WorldModelConfig.from_dict({"deterr": 3})


def _fit(tmp_path: Path, checkpoint_dir: Path | None, seed: int = 0):
    from simeval.episodes.dataset import WindowSpec
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group
    from simeval.models.world_model_training import TrainConfig

    src = make_group("diverse", 2, 3, 10, 16, seed=0)
    return fit_and_evaluate(src, 2, Training(preset("tiny"), TrainConfig(epochs=1, batch_size=4, lr=1e-3, seed=seed),
                                             WindowSpec(length=6, stride=3)),
                            Evaluation(episodes=(0, 3), heldout_episodes=None, seed=0),
                            Execution(checkpoint_dir=checkpoint_dir, progress=False))


def test_a_checkpoint_is_keyed_by_the_training_data_s_content_not_only_its_names_and_lengths(tmp_path):
    """Two groups with the same tasks, seeds, lengths, states and actions whose frames differ (a red and a faint
    disk) must not share a model; the same data again must find the first run's checkpoint."""
    from simeval.episodes.dataset import ArraySource, WindowSpec
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group
    from simeval.models.world_model_training import TrainConfig

    first = make_group("diverse", 2, 3, 10, 16, seed=0)
    fainter = ArraySource(first.infos, [{**a, "image": (a["image"] // 2).astype(np.uint8)} for a in first.arrays])

    def fit(src):
        return fit_and_evaluate(src, 2, Training(preset("tiny"), TrainConfig(epochs=1, batch_size=4, lr=1e-3),
                                                 WindowSpec(length=6, stride=3)),
                                Evaluation(episodes=(0, 3), heldout_episodes=None),
                                Execution(checkpoint_dir=tmp_path, progress=False))["checkpoint"]

    a = fit(first)
    b = fit(fainter)
    assert a != b and sorted(str(p) for p in tmp_path.glob("world_model-*.pt")) == sorted([a, b])
    same = make_group("diverse", 2, 3, 10, 16, seed=0)  # built again: equal arrays, other objects
    assert fit(same) == a
    assert len(list(tmp_path.glob("world_model-*.pt"))) == 2


def test_content_digest_changes_with_any_array_and_not_with_the_objects_holding_them():
    from simeval.episodes.digest import arrays_digest

    rng = np.random.default_rng(0)
    ep = {"image": rng.integers(0, 255, (4, 8, 8, 3), dtype=np.uint8), "state": rng.normal(size=(4, 2)),
          "action": rng.normal(size=(4, 2))}
    base = arrays_digest([ep])
    assert arrays_digest([{k: v.copy() for k, v in ep.items()}]) == base
    for key in ep:
        changed = dict(ep)
        changed[key] = ep[key].copy()
        changed[key].flat[-1] += 1
        assert arrays_digest([changed]) != base, key
    assert arrays_digest([{**ep, "state": ep["state"].astype(np.float32)}]) != base  # dtype is content
    assert arrays_digest([{**ep, "state": ep["state"].reshape(2, 4)}]) != base  # and shape
    assert arrays_digest([ep, ep]) != arrays_digest([ep])  # and how many episodes


def test_evaluation_is_seeded(tmp_path):
    a, b = _fit(tmp_path, None), _fit(tmp_path, None)
    assert a["eval"]["image_error"] == b["eval"]["image_error"]
    assert a["eval"]["open_loop_image_error"] == b["eval"]["open_loop_image_error"]
    assert set(a["eval"]["per_task"]) == {"diverse-0-move", "diverse-1-turn"}
    assert a["eval"]["image_error_per_pixel"] == pytest.approx(a["eval"]["image_error"] / (16 * 16 * 3))


RESUME_SCRIPT = textwrap.dedent("""
    import os, signal, sys, torch
    torch.set_num_threads(1)
    import simeval.models.world_model_training as T
    from simeval.episodes.dataset import WindowSpec
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate, load_model
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group
    from simeval.models.world_model import WorldModelConfig
    kill_at = int(sys.argv[2])
    step = T.step_generator

    def step_or_die(s, i):  # a kill -9 of this process as it reaches step `kill_at`: mid-run, at a known step
        if i == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)
        return step(s, i)

    T.step_generator = step_or_die
    cfg = WorldModelConfig(image_size=16, deter=16, hidden=16, stoch=2, classes=4, cnn_depth=4, minres=4,
                           mlp_layers=1, mlp_units=8)
    v = fit_and_evaluate(make_group("shared", 2, 4, 12, 16), 4,
                         Training(cfg, T.TrainConfig(epochs=3, batch_size=2, lr=1e-3, checkpoint_every=2),
                                  WindowSpec(length=5, stride=2)),
                         Evaluation(episodes=(0, 4), heldout_episodes=None),
                         Execution(checkpoint_dir=sys.argv[1], progress=False))
    print("STEPS", v["train"]["steps"], "FRAMES", v["train"]["frames"], "ERR", repr(v["eval"]["image_error"]))
    model, _ = load_model(v["checkpoint"])
    torch.save(model.state_dict(), sys.argv[1] + "/final.pt")
""")


def test_killed_run_resumes_from_its_checkpoint_and_matches_an_uninterrupted_run(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    script = tmp_path / "fit.py"
    script.write_text(RESUME_SCRIPT)
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    whole.mkdir(), killed.mkdir()
    ref = subprocess.run([sys.executable, str(script), str(whole), "-1"], env=env, capture_output=True, text=True,
                         check=True).stdout
    steps = int(ref.split("STEPS")[1].split()[0])
    assert steps > 7
    killed_run = subprocess.run([sys.executable, str(script), str(killed), "7"], env=env, capture_output=True)
    assert killed_run.returncode == -signal.SIGKILL and b"STEPS" not in killed_run.stdout
    ck = torch.load(next(killed.glob("world_model-*.pt")), weights_only=False)
    assert 0 < ck["step"] <= 7 and not ck["finished"]  # killed part-way, the last checkpoint on disk
    again = subprocess.run([sys.executable, str(script), str(killed), "-1"], env=env, capture_output=True, text=True,
                           check=True)
    # the same evaluation number, and the frames trained on count the whole run, not the part after the resume
    assert again.stdout.split("FRAMES")[1] == ref.split("FRAMES")[1]
    a, b = torch.load(whole / "final.pt"), torch.load(killed / "final.pt")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)


def test_a_checkpoint_gets_the_mode_the_umask_gives_not_mkstemps_0600(tmp_path):
    """A group sharing a checkpoint folder on a cluster must be able to read what a job wrote (policy checkpoints
    are written by the same function)."""
    from simeval.runtime.checkpoints import save_checkpoint

    old = os.umask(0o002)
    try:
        path = save_checkpoint(tmp_path / "ck.pt", {"x": torch.zeros(2)})
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o664
    assert [p.name for p in tmp_path.iterdir()] == ["ck.pt"]  # no temp file left beside it


def _train_logged(caplog, train_cfg, checkpoint=None):
    import logging

    from simeval.episodes.dataset import WindowDataset, WindowSpec
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group
    from simeval.models.world_model_training import train

    src = make_group("diverse", 2, 3, 10, 16, seed=0)
    ds = WindowDataset(src, WindowSpec(length=6, stride=3))  # no random offset: the same batches every epoch
    ds.stats = ds.fit_stats()
    model = WorldModel(preset("tiny"), state_dim=len(ds.stats.state_mean), action_dim=len(ds.stats.action_mean))
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="simeval.models.world_model_training"):
        out = train(model, ds, train_cfg, checkpoint=checkpoint, progress=False, device="cpu")
    return out, len(ds.windows(0)), [r.getMessage() for r in caplog.records]


def test_training_logs_its_planned_steps_and_one_line_per_epoch(caplog, tmp_path):
    """Without progress bars (progress=false, cluster logs) a run still says how long it will take and its pace."""
    from simeval.models.world_model_training import TrainConfig

    out, n_windows, lines = _train_logged(caplog, TrainConfig(epochs=3, batch_size=4, lr=1e-3))
    per_epoch = math.ceil(n_windows / 4)
    assert out["steps"] == 3 * per_epoch
    assert f"training: about {3 * per_epoch} steps (3 epochs x ~{per_epoch} batches of 4 windows), from step 0" in lines
    done = [ln for ln in lines if " done: step " in ln]
    assert [ln.split(",")[0] for ln in done] == [f"epoch {e}/3 done: step {e * per_epoch}" for e in (1, 2, 3)]
    assert done[-1].endswith("~0 s left")

    capped, _, lines = _train_logged(caplog, TrainConfig(epochs=3, batch_size=4, lr=1e-3, max_steps=per_epoch + 1),
                                     checkpoint=tmp_path / "ck.pt")
    assert capped["steps"] == per_epoch + 1
    assert any(ln.startswith(f"training: about {per_epoch + 1} steps") and "capped at" in ln for ln in lines)
    assert [ln.split(",")[0] for ln in lines if " done: step " in ln] == [f"epoch 1/3 done: step {per_epoch}"]
    assert lines[-1] == f"stopped at the step cap: step {per_epoch + 1} (max_steps), in epoch 2/3, after 1 of its batches"

    # resumed from that checkpoint without the cap: the plan counts from where the run stopped
    resumed, _, lines = _train_logged(caplog, TrainConfig(epochs=3, batch_size=4, lr=1e-3),
                                      checkpoint=tmp_path / "ck.pt")
    assert resumed["steps"] == 3 * per_epoch
    assert f"training: about {3 * per_epoch} steps (3 epochs x ~{per_epoch} batches of 4 windows), " \
           f"from step {per_epoch + 1}" in lines
    assert [ln.split(",")[0] for ln in lines if " done: step " in ln] == [f"epoch {e}/3 done: step {e * per_epoch}"
                                                                         for e in (2, 3)]


def test_a_world_model_checkpoint_of_other_settings_is_refused_naming_them(tmp_path):
    """A run folder's checkpoint made for other settings or data (its meta) is not resumed: one line naming the keys."""
    from simeval.episodes.dataset import WindowDataset, WindowSpec
    from simeval.errors import UserError
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group
    from simeval.models.world_model_training import TrainConfig, train

    ds = WindowDataset(make_group("diverse", 2, 2, 8, 16, seed=0), WindowSpec(length=6, stride=3))
    ds.stats = ds.fit_stats()

    def fit(meta):
        model = WorldModel(preset("tiny"), state_dim=len(ds.stats.state_mean), action_dim=len(ds.stats.action_mean))
        return train(model, ds, TrainConfig(epochs=1, batch_size=4, lr=1e-3), checkpoint=tmp_path / "ck.pt",
                     meta=meta, progress=False, device="cpu")

    meta = {"episodes": 2, "world_model": {"rssm": {"deter": 32}}}
    first = fit(meta)
    assert fit(meta)["steps"] == first["steps"]  # the same settings: trained already, reused
    with pytest.raises(UserError, match=r"ck.pt: made with other settings or data \(episodes, "
                                        r"world_model.rssm.deter\); delete it or use another run folder"):
        fit({"episodes": 4, "world_model": {"rssm": {"deter": 64}}})
