"""World-model training throughput per preset (step time, frames/s) and window reading (samples/s).

    python experiments/benchmarks/world_model_bench.py [--presets tiny cpu paper] [--threads 2] [--device auto]
                                                       [--compile]
Writes outputs/bench/world_model.json (with --compile: world_model_compile.json, each preset eager and compiled).
Reference: the authors' PyTorch DreamerV3 fork on a 2-core machine, 5.65 s per training step at 128x128 (the
`paper` settings) and 0.24 s at the `cpu` settings (numbers given in issue 10; not re-measured here; the speed-up
is only comparable with device cpu). The machine's load average is recorded: on a shared machine, steps slow down
with it. `--device` (auto, cpu, cuda, cuda:N) is where the training steps run, recorded in the JSON; window reading
is CPU work either way.
"""

from __future__ import annotations

import os
import tempfile
import time

from common import ROOT, device_info, machine, save, world_model_batch

from simeval.cli import OneLineParser

REFERENCE_STEP_S = {"paper": 5.65, "cpu": 0.24}
STEPS = {"tiny": 20, "cpu": 10, "paper": 4}


def bench_preset(name: str, steps: int, device, compile_steps: bool = False) -> dict:
    import torch
    import yaml

    from simeval.models.world_model import WorldModel, WorldModelConfig

    wm = yaml.safe_load((ROOT / "conf" / "world_model" / f"{name}.yaml").read_text())
    cfg = WorldModelConfig.from_dict(wm["model"])
    b, t = wm["train"]["batch_size"], wm["window"]["length"]
    torch.manual_seed(0)
    model = WorldModel(cfg, state_dim=7, action_dim=7).to(device)  # joint_pos+suction: 6 joints + suction, in and out
    if compile_steps:
        model.compile_steps()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    g = torch.Generator().manual_seed(0)  # the latent samples
    batch = world_model_batch(cfg.image_size, b, t, device)
    # CUDA calls return before the GPU is done: wait for it, or the clock stops early
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)

    def step():
        loss, _ = model.loss(batch, generator=g)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1000.0)
        opt.step()
        sync()

    t0 = time.perf_counter()
    for _ in range(3 if compile_steps else 1):  # warm-up (the compiler's: the first step, and the next shapes)
        step()
    warmup_s = time.perf_counter() - t0
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    step_s = sorted(times)[len(times) // 2]
    out = {"parameters": model.n_parameters(), "image_size": cfg.image_size, "batch": b, "window": t,
           "steps_timed": steps, "step_s_median": round(step_s, 4), "step_s_min": round(min(times), 4),
           "frames_per_s": round(b * t / step_s, 1), "compile": compile_steps, "warmup_s": round(warmup_s, 1)}
    if name in REFERENCE_STEP_S:
        out["reference_step_s"] = REFERENCE_STEP_S[name]
        out["speedup_vs_reference"] = round(REFERENCE_STEP_S[name] / step_s, 2)
    return out


def bench_reading(seconds: float = 8.0) -> dict:
    """Windows per second read from an HDF5 store of synthetic 64x64 episodes (the cpu preset's window), in the
    training thread and through a DataLoader with one worker."""
    import numpy as np

    from simeval.episodes.dataset import StoreSource, WindowDataset, WindowSpec
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group
    from simeval.models.world_model_training import _loader, epoch_batches

    with tempfile.TemporaryDirectory() as tmp:
        paths = write_group(tmp, "diverse", n_tasks=4, episodes=6, n_actions=120, size=64)
        spec = WindowSpec(length=20, stride=10, random_offset=True)
        ds = WindowDataset(StoreSource(paths, "front"), spec)
        ds.stats = ds.fit_stats()
        out = {}
        for workers in (0, 1):
            n, t0 = 0, time.perf_counter()
            epoch = 0
            while time.perf_counter() - t0 < seconds:
                for batch in _loader(ds, epoch_batches(ds.windows(epoch), 8, 0, epoch), workers):
                    n += len(batch["mask"])
                    if time.perf_counter() - t0 >= seconds:
                        break
                epoch += 1
            out[f"workers_{workers}"] = {"windows_per_s": round(n / (time.perf_counter() - t0), 1),
                                         "frames_per_s": round(20 * n / (time.perf_counter() - t0), 1)}
        out["window"] = {"length": 20, "image": "64x64x3 uint8, gzip per frame"}
        out["n_episodes"] = len(paths)
        del np
    return out


def main() -> None:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["tiny", "cpu", "paper"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-reading", action="store_true")
    ap.add_argument("--device", default="auto", help="auto (cuda if available, else cpu) | cpu | cuda | cuda:N")
    ap.add_argument("--compile", action="store_true",
                    help="time each preset eager and with compile=true, side by side (writes world_model_compile.json)")
    a = ap.parse_args()
    import torch

    from simeval.errors import UserError
    from simeval.runtime.device import resolve_device

    try:
        device = resolve_device(a.device, key="--device")
    except UserError as e:
        ap.error(str(e))
    torch.set_num_threads(a.threads)
    result = {"benchmark": "world_model", "machine": machine(), "threads": a.threads, **device_info(device),
              "load_average_before": os.getloadavg(), "presets": {}}
    for name in a.presets:
        for compiled in ([False, True] if a.compile else [False]):
            key = f"{name}+compile" if compiled else name
            result["presets"][key] = bench_preset(name, STEPS.get(name, 5), device, compiled)
            print(key, result["presets"][key], flush=True)
    if not a.no_reading and not a.compile:
        try:
            result["reading"] = bench_reading()
        except Exception as e:  # noqa: BLE001 - the store format may not support it yet; say so in the result
            result["reading"] = {"error": f"{type(e).__name__}: {e}"}
    result["load_average_after"] = os.getloadavg()
    save("world_model_compile" if a.compile else "world_model", result)


if __name__ == "__main__":
    main()
