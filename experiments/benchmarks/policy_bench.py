"""Benchmark: Diffusion Policy training-step time (batch of the preset) and action-chunk latency (one observation,
the preset's sampler) per preset in conf/policy/, with random data of the preset's shapes (12-d state, 7-d or 14-d
action). Reference on this kind of machine (2 CPU cores): the official implementation's U-Net at the `cpu`
settings takes 0.32 s per training step (batch 64) and 0.11 s per 16-step chunk; the `cpu` preset's numbers are
reported as ratios to those (ours include the image encoder, the reference is the U-Net alone).
Usage: policy_bench.py [--presets cpu tiny] [--threads N] [--repeats 5] [--device auto]. Writes
outputs/bench/policy.json, with the device (auto: cuda if available, else cpu) the steps ran on; the ratios to the
reference are only meaningful on cpu.
"""

from __future__ import annotations

import os
import time

import torch
import yaml
from common import ROOT, device_info, machine, save

from simeval.cli import OneLineParser
from simeval.errors import UserError
from simeval.runtime.device import resolve_device
from simeval.models.diffusion_policy import DiffusionPolicy, PolicyConfig

REFERENCE = {"train_step_s": 0.32, "chunk_s": 0.11}  # official U-Net at the cpu settings, batch 64 / 16 steps


def _timed(fn, repeats: int, device: torch.device) -> float:
    # CUDA calls return before the GPU is done: wait for it, or the clock stops early
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    fn()  # warm-up
    sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2]  # median


def bench(preset: str, repeats: int, device: torch.device) -> dict:
    spec = yaml.safe_load((ROOT / "conf" / "policy" / f"{preset}.yaml").read_text())
    cfg = PolicyConfig.from_mapping(spec["model"])
    batch_size = spec["train"]["batch_size"]
    a_dim = 14 if cfg.action_space == "pick_place" else 7
    policy = DiffusionPolicy(cfg, 12, a_dim, seed=0).to(device)
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-4)
    h, w = cfg.image_size

    def batch(b):  # on the device already: the step is timed, not the copy
        return {"rgb": {c: torch.randint(0, 255, (b, cfg.n_obs_steps, h, w, 3), dtype=torch.uint8, device=device)
                        for c in cfg.cameras},
                "state": torch.randn(b, cfg.n_obs_steps, 12, device=device),
                "action": torch.randn(b, cfg.horizon, a_dim, device=device)}

    train_batch, obs = batch(batch_size), batch(1)

    def step():
        loss = policy.compute_loss(train_batch)
        opt.zero_grad()
        loss.backward()
        opt.step()

    def unet_step():
        cond = torch.randn(batch_size, _cond_dim(policy), device=device)
        t = torch.randint(0, 100, (batch_size,), device=device)
        loss = policy.unet(train_batch["action"], t, cond).pow(2).mean()
        opt.zero_grad()
        loss.backward()

    with torch.no_grad():
        chunk = _timed(lambda: policy.predict_action(obs), repeats, device)
    out = {"batch_size": batch_size, "sampler": cfg.inference_scheduler, "sampler_steps": cfg.num_inference_steps
           if cfg.inference_scheduler == "ddim" else cfg.num_train_timesteps,
           "params_m": round(sum(p.numel() for p in policy.parameters()) / 1e6, 3),
           "unet_params_m": round(sum(p.numel() for p in policy.unet.parameters()) / 1e6, 3),
           "train_step_s": round(_timed(step, repeats, device), 4),
           "unet_train_step_s": round(_timed(unet_step, repeats, device), 4),
           "chunk_s": round(chunk, 4)}
    if preset == "cpu":
        out["ratio_to_reference"] = {"train_step": round(out["train_step_s"] / REFERENCE["train_step_s"], 2),
                                     "unet_train_step": round(out["unet_train_step_s"] / REFERENCE["train_step_s"], 2),
                                     "chunk": round(out["chunk_s"] / REFERENCE["chunk_s"], 2)}
    return out


def _cond_dim(policy: DiffusionPolicy) -> int:
    cfg = policy.cfg
    return cfg.n_obs_steps * (len(cfg.cameras) * cfg.feature_dim + policy.state_dim)


def main() -> None:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["tiny", "cpu", "authors_gensim", "official"])
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's, all cores)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default="auto", help="auto (cuda if available, else cpu) | cpu | cuda | cuda:N")
    args = ap.parse_args()
    try:
        device = resolve_device(args.device, key="--device")
    except UserError as e:
        ap.error(str(e))
    if args.threads:
        torch.set_num_threads(args.threads)
    result = {"benchmark": "policy", "machine": machine(), "torch_threads": torch.get_num_threads(),
              **device_info(device), "load_average_at_start": list(os.getloadavg()), "reference": REFERENCE,
              "presets": {p: bench(p, args.repeats, device) for p in args.presets}}
    result["load_average_at_end"] = list(os.getloadavg())
    save("policy", result)


if __name__ == "__main__":
    main()
