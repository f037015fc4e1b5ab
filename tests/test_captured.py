"""The world-model training step that CUDA graphs replay (simeval.runtime.captured): on the CPU, the same step run
eagerly against train()'s own loop written out here (noise passed in, resets read on the CPU, Adam after the
pass), bit for bit; capture=true without a GPU refused in one line. On a GPU (marked `gpu`): train(capture=True)
against train(capture=False), loss by loss over 100+ steps. Self-contained (no helpers, no conftest fixtures), so
`pytest --noconftest -m gpu tests/test_captured.py` runs on a GPU machine that has only torch, numpy, einops, tqdm
and PyYAML."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
import torch
import yaml

from simeval.episodes.dataset import WindowDataset, WindowSpec
from simeval.errors import UserError
from simeval.runtime.captured import CapturedTrainStep
from simeval.measures.dynamics_diversity.controls.synthetic import make_group
from simeval.models.world_model_training import TrainConfig, step_generator, train
from simeval.models.world_model import WorldModel, WorldModelConfig

ROOT = Path(__file__).resolve().parents[1]
CUDA = torch.cuda.is_available()
os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # before cuBLAS starts: deterministic kernels on a GPU


def tiny(state_dim: int = 3, action_dim: int = 2) -> WorldModel:
    cfg = WorldModelConfig.from_dict(yaml.safe_load((ROOT / "conf" / "world_model" / "tiny.yaml").read_text())["model"])
    torch.manual_seed(0)
    return WorldModel(cfg, state_dim=state_dim, action_dim=action_dim)


def batch(seed: int, resets: list[tuple[int, int]], b: int = 3, t: int = 6, size: int = 16) -> dict:
    """A random batch whose rows reset where `resets` (row, step) say: none at all, mid-window, or at the start."""
    g = torch.Generator().manual_seed(seed)
    is_first = torch.zeros(b, t, dtype=torch.bool)
    for row, step in resets:
        is_first[row, step] = True
    return {"image": torch.randint(0, 256, (b, t, size, size, 3), generator=g, dtype=torch.uint8),
            "state": torch.randn(b, t, 3, generator=g), "prev_action": torch.randn(b, t, 2, generator=g),
            "is_first": is_first, "mask": torch.ones(b, t, dtype=torch.bool)}


BATCHES = [batch(0, [(0, 0), (1, 0), (2, 0)]), batch(1, []), batch(2, [(1, 3)]), batch(3, []), batch(4, [(2, 5)]),
           batch(5, [(0, 0)])]


def test_the_step_a_graph_holds_trains_to_the_numbers_of_trains_own_loop():
    """CapturedTrainStep(capture=False) runs eagerly what a capture records: the latent noise comes in as a tensor
    drawn from the step's generator, the resets are read from the batch on the CPU, Adam steps on the gradients
    the pass left. Against train()'s loop on batches with no reset, a reset mid-window and resets at the start, the
    metrics and the weights after every step are the same to the bit."""
    eager, graph_form = tiny(), tiny()
    opt_e = torch.optim.Adam(eager.parameters(), lr=1e-3)
    opt_g = torch.optim.Adam(graph_form.parameters(), lr=1e-3)
    stepper = CapturedTrainStep(graph_form, opt_g, clip=1000.0, capture=False)
    for i, x in enumerate(BATCHES * 2):
        loss, want = eager.loss(x, generator=step_generator(0, i))
        opt_e.zero_grad(set_to_none=True)
        loss.backward()
        want["grad_norm"] = float(torch.nn.utils.clip_grad_norm_(eager.parameters(), 1000.0))
        opt_e.step()
        assert stepper(x, step_generator(0, i)) == want, i
        for (name, a), b in zip(eager.state_dict().items(), graph_form.state_dict().values()):
            assert torch.equal(a, b), (i, name)


def test_capture_without_a_gpu_is_one_line():
    model = tiny()
    with pytest.raises(UserError) as e:
        CapturedTrainStep(model, torch.optim.Adam(model.parameters()), clip=1000.0, capture=True)
    # device=cuda is suggested only where there is one (a fresh-clone trial was told to use it on a CPU machine)
    fix = ("capture=false or device=cuda" if torch.cuda.is_available() else
           "capture=false (this machine has no CUDA GPU)")
    assert str(e.value) == f"capture=true needs a CUDA GPU (the model is on cpu); use {fix}"
    with pytest.raises(UserError, match=r"^capture=true needs a CUDA GPU \(the device is cpu\); use "
                                        + re.escape(fix) + "$"):
        train(tiny(), dataset(), TrainConfig(epochs=1, batch_size=4), progress=False, device="cpu", capture=True)


def dims(ds: WindowDataset) -> tuple[int, int]:
    return len(ds.stats.state_mean), len(ds.stats.action_mean)


def dataset(seed: int = 0) -> WindowDataset:
    ds = WindowDataset(make_group("diverse", 2, 3, 10, 16, seed=seed), WindowSpec(length=6, stride=3),
                       image_size=16, seed=seed)
    ds.stats = ds.fit_stats()
    return ds


# --- on a GPU (skipped without one) -------------------------------------------------------------------------------
@pytest.mark.gpu
@pytest.mark.skipif(not CUDA, reason="torch sees no GPU")
def test_captured_training_on_a_gpu_follows_eager_training_loss_for_loss(tmp_path, monkeypatch):
    """train(capture=True) on CUDA against train(capture=False) on CUDA, same data and seeds, 100+ steps with an
    epoch-end batch of another size (run eagerly beside the graphs): the graphs really replayed, every step's loss
    within 1e-5 (relative), the segments say how it trained, and the checkpoint holds CPU tensors that an eager
    CPU process resumes as finished. Deterministic kernels: without them eager training differs from itself on a
    GPU by up to ~6e-5 within 100 steps (outputs/bench/world_model_gpu_h200.json), and that is not the graph's."""
    monkeypatch.setattr(torch.backends.cudnn, "benchmark", False)
    replays = []
    replay = torch.cuda.CUDAGraph.replay
    monkeypatch.setattr(torch.cuda.CUDAGraph, "replay", lambda self: (replays.append(1), replay(self))[1])
    ds = dataset()
    cfg = TrainConfig(epochs=40, batch_size=5, lr=1e-3, checkpoint_every=50)
    assert len(ds.windows(0)) % cfg.batch_size, "the test wants a shorter last batch per epoch"
    losses: dict[bool, list[float]] = {True: [], False: []}
    summaries = {}
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        for capture in (False, True):
            summaries[capture] = train(tiny(*dims(ds)), ds, cfg, checkpoint=tmp_path / f"{capture}.ckpt",
                                       log_metrics=lambda m, step, c=capture: losses[c].append(m["train"]["loss"]),
                                       progress=False, device="cuda", capture=capture)
    finally:
        torch.use_deterministic_algorithms(False)
    assert len(losses[True]) == len(losses[False]) >= 100
    assert len(replays) >= len(losses[True]) // 2
    for i, (a, b) in enumerate(zip(losses[True], losses[False])):
        assert a == pytest.approx(b, rel=1e-5), i
    assert summaries[True]["segments"][-1]["capture"] is True
    ck = torch.load(tmp_path / "True.ckpt", weights_only=False)
    assert all(v.device.type == "cpu" for v in ck["model"].values())
    again = train(tiny(*dims(ds)), ds, cfg, checkpoint=tmp_path / "True.ckpt", progress=False, device="cpu")
    assert again["steps"] == summaries[True]["steps"]
