"""The validity control (simeval.models.synthetic; experiments/world_model_control.py): a group of tasks with k
distinct dynamics must get a higher world-model error at 10 episodes per task and a larger 10 -> 40 drop than a
group whose tasks share one dynamics (same colours, same starts, same actions). Tiny preset, 6 epochs, one seed
(~1 min on 2 cores); the experiment runs seeds 0 and 1 and 10/20/40 episodes."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.timeout(600)
def test_diverse_dynamics_rank_above_shared_dynamics():
    import torch

    from world_model_control import run

    result = run("tiny", seeds=[0], episodes=[10, 40], n_tasks=4, n_actions=16, epochs=6, threads=1)
    torch.set_num_threads(1)
    for metric in ("image_error", "open_loop_image_error", "state_error"):
        (v,) = result["verdict"][metric]
        assert v["higher_at_few"], (metric, result["rows"])
        assert v["larger_drop"], (metric, result["rows"])
