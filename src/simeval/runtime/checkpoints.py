"""Checkpoint files of both models (the world model's, simeval.models.world_model_training; the policy's,
simeval.models.diffusion_policy): written atomically, read onto the CPU with one error for a file that is not one.
Each model checks its own format and fields after read_checkpoint.

    save_checkpoint(path, payload) -> Path        # torch.save through a temp file + rename, the umask's mode
    read_checkpoint(path, what) -> dict           # torch.load(map_location="cpu"); UserError naming `what`
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from simeval.errors import UserError
from simeval.results import atomic_path


def save_checkpoint(path: str | os.PathLike, payload: dict) -> Path:
    """torch.save through simeval.results.atomic_path: a kill never leaves half a checkpoint, and the file gets the
    umask's mode (a group sharing a checkpoint folder on a cluster reads what a job wrote)."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


def read_checkpoint(path: str | os.PathLike, what: str) -> dict:
    """The payload of a checkpoint file, its tensors on the CPU (one trained on a GPU loads anywhere). A file torch
    cannot read, or one that holds no mapping, is one UserError naming the file and `what` it should have been."""
    if not Path(path).is_file():
        raise UserError(f"{path}: no such {what} checkpoint file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # any unreadable file (truncated, not torch's, a pickle of a missing class) is one problem
        raise UserError(f"{path}: not a readable {what} checkpoint ({type(e).__name__}: {e}); delete it to start "
                        "over") from e
    if not isinstance(payload, dict):
        raise UserError(f"{path}: not a {what} checkpoint (it holds a {type(payload).__name__}); delete it to start "
                        "over")
    return payload
