"""World-model training steps on a GPU: the variants side by side in one process, with where the time goes.

    python experiments/benchmarks/world_model_gpu.py [--presets cpu paper] [--window 40] [--baseline FILE]
        [--variants eager compile capture compile+capture bf16] [--agree-steps 100] [--out FILE]
Writes outputs/bench/world_model_gpu.json, or --out (GPU timings are only comparable on the same card: the JSON
names it).

Variants (each from the same initial weights, on the same random batch; the first loss of each is recorded, so a
variant that computes something else shows):
  eager      the training step as simeval runs it (device=cuda)
  compile    the same with compile=true (WorldModel.compile_steps: torch.compile of the encoder, the decoder and
             the RSSM's per-step functions); the warm-up's seconds, compilation included, are recorded apart
  capture    the whole step (forward, backward, clipping, Adam) as one CUDA graph, replayed (capture=true:
             simeval.runtime.captured.CapturedTrainStep, what train() runs); the warm-up's seconds, the capture
             included, are recorded apart
  compile+capture  both: the compiled steps' kernels captured in the graph
  bf16       eager under torch.autocast(bfloat16): what mixed precision would give (simeval trains in float32)
Agreement (--agree-steps N): N training steps of eager (train()'s loop) and of capture from the same weights, on a
cycle of four batches with different resets (none, mid-window, at the start), each step's loss side by side: the
largest relative difference says whether the graph trains the same model.
  baseline   with --baseline FILE: the WorldModel class of another version of simeval/models/world_model.py
             (e.g. `git show <rev>:src/simeval/models/world_model.py > /tmp/wm_before.py`), for a before/after
Where the time goes (eager): torch.profiler sums the GPU kernels' time of one step; a step whose kernels take a
fraction of its wall time is bound by launching them from Python (the RSSM's steps are sequential, batch 8).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

from common import ROOT, device_info, machine, save, world_model_batch

from simeval.cli import OneLineParser


def write(result: dict, out: str | None) -> None:
    if out is None:
        save("world_model_gpu", result)
    else:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=2) + "\n")


def load_baseline(path: str):
    spec = importlib.util.spec_from_file_location("world_model_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def time_variant(model_cls, cfg, batch, steps: int, device, variant: str) -> dict:
    import torch

    from simeval.runtime.captured import CapturedTrainStep
    from simeval.models.world_model_training import step_generator

    torch.manual_seed(0)
    model = model_cls(cfg, state_dim=7, action_dim=7).to(device)
    compile_s = None
    if "compile" in variant:
        model.compile_steps()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    autocast = torch.autocast("cuda", dtype=torch.bfloat16, enabled=variant == "bf16")
    captured = CapturedTrainStep(model, opt, 1000.0) if "capture" in variant else None
    host_batch = pinned(batch) if captured is not None else None  # copied in per step as in train(): timed too

    def step(i: int) -> float:
        if captured is not None:
            return captured(host_batch, step_generator(0, i))["loss"]
        with autocast:
            loss, metrics = model.loss(batch, generator=step_generator(0, i))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1000.0)
        opt.step()
        torch.cuda.synchronize()
        return metrics["loss"]

    t0 = time.perf_counter()
    first_loss = step(0)
    # warm-up: cuDNN's algorithm search, the compiler's second graph (is_first differs), the capture
    for i in range(1, 5 if captured is not None else 3):
        step(i)
    warmup_s = time.perf_counter() - t0
    if variant != "eager":
        compile_s = round(warmup_s, 1)
    times = []
    for i in range(steps):
        t1 = time.perf_counter()
        step(100 + i)
        times.append(time.perf_counter() - t1)
    times.sort()
    out = {"step_s_median": round(times[len(times) // 2], 4), "step_s_min": round(times[0], 4),
           "steps_timed": steps, "first_loss": round(first_loss, 3),
           "peak_memory_gib": round(torch.cuda.max_memory_allocated(device) / 2**30, 2)}
    if compile_s is not None:
        out["warmup_s"] = compile_s
    if captured is not None:
        out["graphs"] = len(captured.graphs)
    torch.cuda.reset_peak_memory_stats(device)
    return out


def kernel_time(model_cls, cfg, batch, device) -> dict:
    """GPU kernel time of one eager step (torch.profiler) against its wall time."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    torch.manual_seed(0)
    model = model_cls(cfg, state_dim=7, action_dim=7).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)

    def step():
        loss, _ = model.loss(batch, generator=torch.Generator().manual_seed(0))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1000.0)
        opt.step()
        torch.cuda.synchronize()

    for _ in range(2):
        step()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        t0 = time.perf_counter()
        step()
        wall = time.perf_counter() - t0
    kernels = [e for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA]
    busy = sum(e.time_range.elapsed_us() for e in kernels) / 1e6
    return {"wall_s_profiled": round(wall, 4), "kernels": len(kernels), "kernel_s": round(busy, 4),
            "kernel_fraction": round(busy / wall, 3)}


def pinned(batch: dict) -> dict:
    import torch

    return {k: v.cpu().pin_memory() if torch.cuda.is_available() else v.cpu() for k, v in batch.items()}


def agreement_batches(image_size: int, b: int, length: int, device) -> list[dict]:
    """Four batches of the benchmark's random frames (rolled in time so they differ) with resets at the start of
    every row, nowhere, mid-window in one row, and at two steps of two rows."""
    base = world_model_batch(image_size, b, length, device)
    patterns = [[(r, 0) for r in range(b)], [], [(0, length // 2)], [(1, 1), (b - 1, length - 2)]]
    out = []
    for k, resets in enumerate(patterns):
        x = {key: v.roll(k * 3, dims=1).clone() for key, v in base.items()}
        x["is_first"].zero_()
        for row, t in resets:
            x["is_first"][row, t] = True
        out.append(x)
    return out


def agreement(cfg, batches: list[dict], steps: int, device) -> dict:
    """Eager training (train()'s loop) against the captured step, from the same weights, loss by loss."""
    import torch

    from simeval.runtime.captured import CapturedTrainStep
    from simeval.models.world_model_training import step_generator
    from simeval.models.world_model import WorldModel

    def fresh():
        torch.manual_seed(0)
        model = WorldModel(cfg, state_dim=7, action_dim=7).to(device)
        return model, torch.optim.Adam(model.parameters(), lr=1e-4)

    def eager_losses() -> list[float]:
        model, opt = fresh()
        out = []
        for i in range(steps):
            loss, metrics = model.loss(batches[i % len(batches)], generator=step_generator(0, i))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1000.0)
            opt.step()
            out.append(metrics["loss"])
        return out

    def worst(a: list[float], b: list[float]) -> tuple[float, int]:
        rel = [abs(x - y) / abs(y) for x, y in zip(a, b)]
        i = max(range(len(rel)), key=rel.__getitem__)
        return rel[i], i

    losses_eager, again = eager_losses(), eager_losses()  # the second: how far eager is from itself
    model, opt = fresh()
    captured = CapturedTrainStep(model, opt, 1000.0)
    cpu_batches = [pinned(x) for x in batches]  # as train()'s loader gives them
    losses_captured = [captured(cpu_batches[i % len(batches)], step_generator(0, i))["loss"] for i in range(steps)]
    rel, at = worst(losses_captured, losses_eager)
    return {"steps": steps, "graphs": len(captured.graphs), "max_rel_diff": rel, "at_step": at,
            "within_1e-5": rel <= 1e-5, "identical": losses_captured == losses_eager,
            "eager_rerun_max_rel_diff": worst(again, losses_eager)[0],
            "loss_eager": [round(v, 4) for v in losses_eager], "loss_captured": [round(v, 4) for v in losses_captured]}


def main() -> None:
    ap = OneLineParser(description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    ap.add_argument("--window", type=int, nargs="+", default=None,
                    help="window lengths to time (default: each preset's own)")
    ap.add_argument("--variants", nargs="+", default=["eager", "compile", "capture", "compile+capture", "bf16"])
    ap.add_argument("--baseline", default=None, help="another world_model.py to time beside (variant 'baseline')")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--agree-steps", type=int, default=0,
                    help="steps of eager against captured training, loss by loss (0: none)")
    ap.add_argument("--deterministic", action="store_true",
                    help="agreement with deterministic kernels (torch.use_deterministic_algorithms; set "
                         "CUBLAS_WORKSPACE_CONFIG=:4096:8): eager then repeats itself, so any difference is the graph's")
    ap.add_argument("--out", default=None, help="where the JSON goes (default outputs/bench/world_model_gpu.json)")
    a = ap.parse_args()
    import torch
    import yaml

    from simeval.models.world_model import WorldModel, WorldModelConfig

    if not torch.cuda.is_available():
        ap.error("needs a GPU (torch sees none); experiments/benchmarks/world_model_bench.py times the CPU")
    device = torch.device("cuda")
    variants = (["baseline"] if a.baseline else []) + a.variants
    baseline = load_baseline(a.baseline) if a.baseline else None
    result = {"benchmark": "world_model_gpu", "machine": machine(), **device_info(device), "presets": {}}
    for name in a.presets:
        wm = yaml.safe_load((ROOT / "conf" / "world_model" / f"{name}.yaml").read_text())
        for length in a.window or [wm["window"]["length"]]:
            key = f"{name}/window{length}"
            b = wm["train"]["batch_size"]
            cfg = WorldModelConfig.from_dict(wm["model"])
            batch = world_model_batch(cfg.image_size, b, length, device)
            row = {"batch": b, "window": length, "image_size": cfg.image_size}
            for v in variants:
                cls = baseline.WorldModel if v == "baseline" else WorldModel
                c = baseline.WorldModelConfig.from_dict(wm["model"]) if v == "baseline" else cfg
                try:
                    row[v] = time_variant(cls, c, batch, a.steps, device, v)
                    row[v]["frames_per_s"] = round(b * length / row[v]["step_s_median"], 1)
                except Exception as e:  # noqa: BLE001 - a variant that fails on this stack is a finding, not a stop
                    row[v] = {"error": f"{type(e).__name__}: {str(e)[:300]}"}
                print(key, v, row[v], flush=True)
            row["eager_profile"] = kernel_time(WorldModel, cfg, batch, device)
            print(key, "profile", row["eager_profile"], flush=True)
            if a.agree_steps:
                try:
                    if a.deterministic:
                        torch.use_deterministic_algorithms(True, warn_only=True)
                        torch.backends.cudnn.benchmark = False
                    row["agreement"] = agreement(cfg, agreement_batches(cfg.image_size, b, length, device),
                                                 a.agree_steps, device)
                except Exception as e:  # noqa: BLE001 - as a variant's failure: recorded, the other presets go on
                    row["agreement"] = {"error": f"{type(e).__name__}: {str(e)[:300]}"}
                finally:
                    torch.use_deterministic_algorithms(False)
                row["agreement"]["deterministic"] = a.deterministic
                print(key, "agreement", {k: v for k, v in row["agreement"].items() if not k.startswith("loss")},
                      flush=True)
            result["presets"][key] = row
            write(result, a.out)  # after each preset: a run stopped at its time limit keeps the rest
    print(f"\n{'preset/window':<20}" + "".join(f"{v:>12}" for v in variants))
    for key, row in result["presets"].items():
        print(f"{key:<20}" + "".join(f"{row[v].get('step_s_median', float('nan')):>12.4f}" for v in variants))


if __name__ == "__main__":
    main()
