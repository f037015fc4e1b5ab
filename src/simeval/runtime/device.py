"""Which torch device the models train and run on: the `device` option of src/diversity.py and
src/generalization.py, and the `device` argument of the library functions behind them.

    resolve_device(value, key="device") -> torch.device
        "auto" or None: cuda when torch.cuda.is_available(), else cpu; "cpu"; "cuda" (the current GPU); "cuda:N".
        Anything else, or a CUDA device this machine lacks, is a UserError naming the key, the value and what
        would be valid here.
    to_device(obj, device): the tensors of a (nested) dict on `device`, other values as they are.
    to_cpu(obj): the tensors of a nested dict/list/tuple on the CPU: what checkpoints store, so that one written on
        a GPU loads on a machine without one (and a checkpoint's device is never part of what it is).
    module_device(module): where a module's parameters are; evaluation and sampling bring their inputs there.
    describe_device(device) -> {"device", "torch", "gpu" (on CUDA)}: what a timing or a result ran on.

Randomness stays on the CPU: the models draw their random tensors from seeded CPU torch.Generators and move them to
the device (small next to the model's own work), so a seed gives the same samples on every device, and device=cpu
gives exactly the numbers the code gave before it had a device option.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping

import torch

from simeval.errors import UserError

VALID = "auto, cpu, cuda, cuda:N"
_CUDA = re.compile(r"cuda(?::(\d+))?")


def _no_cuda_reason() -> str:
    if torch.version.cuda is None:
        return f"torch {torch.__version__} is a CPU-only build"
    return f"torch {torch.__version__} (CUDA {torch.version.cuda}) sees no GPU"


def resolve_device(value: str | torch.device | None = "auto", key: str = "device") -> torch.device:
    """The torch.device that `value` names (see the module docstring); "cuda" and "auto" on a GPU machine resolve
    to an explicit index (cuda:0 unless torch.cuda.set_device says otherwise), so the device recorded with a result
    says which GPU ran it."""
    if isinstance(value, torch.device):
        value = str(value)
    if value is None or value == "auto":
        value = "cuda" if torch.cuda.is_available() else "cpu"
    if value == "cpu":
        return torch.device("cpu")
    match = _CUDA.fullmatch(value) if isinstance(value, str) else None
    if match is None:
        raise UserError(f"{key}={value!r}: expected one of {VALID} (N: a GPU's index)")
    if not torch.cuda.is_available():
        raise UserError(f"{key}={value!r}: CUDA is not available here ({_no_cuda_reason()}); available: auto "
                        f"(= cpu here), cpu")
    index = torch.cuda.current_device() if match.group(1) is None else int(match.group(1))
    count = torch.cuda.device_count()
    if index >= count:
        raise UserError(f"{key}={value!r}: this machine has {count} CUDA device(s); available: auto, cpu, "
                        f"{', '.join(f'cuda:{i}' for i in range(count))}")
    return torch.device("cuda", index)


def to_device(obj, device: torch.device, non_blocking: bool = False):
    """`obj` with its tensors on `device` (dicts are walked, e.g. a policy batch's {"rgb": {cam: ...}}). A tensor
    already there is returned as it is, no copy. non_blocking only overlaps the copy with computation when the
    source is in pinned memory (a DataLoader with pin_memory)."""
    if isinstance(obj, torch.Tensor):
        return obj.to(device, non_blocking=non_blocking)
    if isinstance(obj, Mapping):
        return {k: to_device(v, device, non_blocking) for k, v in obj.items()}
    return obj


def to_cpu(obj):
    """`obj` (a state_dict, an optimiser's, nested dicts/lists/tuples) with every tensor on the CPU; CPU tensors are
    returned as they are, so on a CPU run the saved checkpoint is the same as without this."""
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        out = copy.copy(obj)  # keeps the type and a state_dict's _metadata (module versions load_state_dict reads)
        for k, v in obj.items():
            out[k] = to_cpu(v)
        return out
    if type(obj) in (list, tuple):
        return type(obj)(to_cpu(v) for v in obj)
    return obj


def module_device(module: torch.nn.Module) -> torch.device:
    return next(module.parameters()).device


def describe_device(device: torch.device) -> dict:
    """What steps ran on: the torch.device, torch's build (a +cpu one cannot use a GPU) and, for a GPU, its name
    (timings and last-bit rounding differ by model)."""
    info = {"device": str(device), "torch": torch.__version__}
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    return info
