"""Both models' checkpoint files go through simeval.runtime.checkpoints: a file that is not a checkpoint is one
UserError naming it and the model, whichever model reads it."""

from __future__ import annotations

import pytest
import torch

from simeval.errors import UserError
from simeval.models import diffusion_policy
from simeval.models import world_model_training as training
from simeval.runtime.checkpoints import read_checkpoint, save_checkpoint


def test_a_truncated_or_foreign_file_is_one_error_naming_the_model(tmp_path):
    whole = save_checkpoint(tmp_path / "whole.pt", {"format": training.CHECKPOINT_FORMAT, "x": torch.ones(3)})
    assert torch.equal(read_checkpoint(whole, "world-model")["x"], torch.ones(3))
    cut = tmp_path / "cut.pt"
    cut.write_bytes(whole.read_bytes()[:40])  # a copy that stopped half way
    with pytest.raises(UserError, match=r"cut\.pt: not a readable world-model checkpoint .*delete it to start over"):
        training.load_checkpoint(cut)
    with pytest.raises(UserError, match=r"cut\.pt: not a readable policy checkpoint"):
        diffusion_policy.load_checkpoint(cut)
    listed = save_checkpoint(tmp_path / "list.pt", [1, 2])
    with pytest.raises(UserError, match=r"list\.pt: not a policy checkpoint \(it holds a list\)"):
        diffusion_policy.load_checkpoint(listed)
    # readable, but the other model's: each model checks its own format
    with pytest.raises(UserError, match=r"not a simeval policy checkpoint of version \d+ \(version None\)"):
        diffusion_policy.load_checkpoint(whole)
    world_model_like = save_checkpoint(tmp_path / "wm.pt", {"format": training.CHECKPOINT_FORMAT, "meta": {}})
    with pytest.raises(UserError, match=r"not a simeval policy checkpoint .*\(a world-model checkpoint\)"):
        diffusion_policy.load_checkpoint(world_model_like)
    policy_like = save_checkpoint(tmp_path / "p.pt", {"version": diffusion_policy.CHECKPOINT_VERSION,
                                                       "policy_config": {}})
    with pytest.raises(UserError, match=r"p\.pt: not a world-model checkpoint of format \d+ \(a policy checkpoint\)"):
        training.load_checkpoint(policy_like)
    with pytest.raises(UserError, match=r"whole\.pt: not a world-model checkpoint of format \d+ \(format 99\)"):
        training.load_checkpoint(save_checkpoint(tmp_path / "whole.pt", {"format": 99}))
    with pytest.raises(UserError, match=r"gone\.pt: no such world-model checkpoint file"):
        training.load_checkpoint(tmp_path / "gone.pt")
