"""What every benchmark script shares: where results go and how they are written."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def machine() -> dict:
    return {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}


def device_info(device) -> dict:
    """What the timed steps ran on (simeval.runtime.device.describe_device)."""
    from simeval.runtime.device import describe_device

    return describe_device(device)


def save(name: str, result: dict) -> Path:
    """Write outputs/bench/<name>.json and print it."""
    path = ROOT / "outputs" / "bench" / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(result, indent=2) + "\n"
    path.write_text(text)
    print(text, end="")
    return path


def world_model_batch(image_size: int, batch: int, steps: int, device, dims: int = 7) -> dict:
    """A seeded random world-model batch (uint8 frames, `dims`-dimensional state and action, a reset at each window's
    first step) already on `device`, so a benchmark times the training step and not the copy."""
    import torch

    g = torch.Generator().manual_seed(0)
    is_first = torch.zeros(batch, steps, dtype=torch.bool)
    is_first[:, 0] = True
    out = {"image": torch.randint(0, 256, (batch, steps, image_size, image_size, 3), generator=g, dtype=torch.uint8),
           "state": torch.randn(batch, steps, dims, generator=g),
           "prev_action": torch.randn(batch, steps, dims, generator=g),
           "is_first": is_first, "mask": torch.ones(batch, steps, dtype=torch.bool)}
    return {k: v.to(device) for k, v in out.items()}
