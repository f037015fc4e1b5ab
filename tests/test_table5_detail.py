"""Table 5's honest companions: the task-level (cluster) bootstrap interval of a group's rate against its normal
approximation, the random-policy baseline's actions, and the per-task detail table from hand-built records."""

from __future__ import annotations

import numpy as np
import pytest

from simeval.metrics.intervals import task_bootstrap_interval, wilson_interval
from simeval.models.policy.random_baseline import RandomActions
from simeval.models.policy.table5 import detail_rows, write_detail


def test_task_bootstrap_matches_the_normal_approximation_with_many_tasks():
    """Equal rollouts per task: the pooled rate is the mean of the task rates, whose bootstrap standard error is
    sqrt(popvar(rates) / T); with T = 300 tasks the percentile interval is close to mean +- 1.96 se."""
    rng = np.random.default_rng(0)
    n = np.full(300, 10)
    k = rng.binomial(10, rng.beta(1, 3, 300))
    rates = k / n
    lo, hi = task_bootstrap_interval(k, n, n_boot=8000)
    half = 1.96 * np.sqrt(rates.var() / len(rates))
    assert abs((hi - lo) / 2 / half - 1) < 0.1
    assert abs((hi + lo) / 2 - rates.mean()) < 0.2 * half


def test_task_interval_is_wider_than_wilson_when_one_task_holds_every_success():
    k, n = [5, 0, 0, 0, 0, 0], [5, 5, 5, 5, 5, 5]  # bbsea/drawer: all 5 successes on close-drawer
    task_lo, task_hi = task_bootstrap_interval(k, n)
    w_lo, w_hi = wilson_interval(5, 30)
    assert task_lo == 0.0 and task_hi - task_lo > w_hi - w_lo
    assert task_bootstrap_interval([3], [10]) is None  # one task: nothing to resample


def test_random_actions_are_seeded_and_inside_the_box():
    from gymnasium import spaces

    space = spaces.Box(np.array([-1.0, 0.0, 5.0], np.float32), np.array([1.0, 0.5, 6.0], np.float32))
    env = type("Env", (), {"action_space": space})()
    runner = RandomActions("joint").runner(env)
    draws = []
    for seed in (3, 3, 4):
        runner.reset(seed)
        draws.append(np.stack([runner.act(None) for _ in range(200)]))
    np.testing.assert_array_equal(draws[0], draws[1])
    assert not np.array_equal(draws[0], draws[2])
    assert np.all(draws[0] >= space.low) and np.all(draws[0] <= space.high)
    assert np.all(np.abs(draws[0].mean(0) - (space.low + space.high) / 2) < 0.1 * (space.high - space.low))


def _record(policy: str, tasks: list[tuple[str, str, list[tuple[bool, float]]]]) -> dict:
    rows = [{"split": split, "task": task,
             "success": {"k": sum(s for s, _ in eps), "n": len(eps)},
             "episodes": [{"seed": i, "success": s, "progress": p, "steps": 1} for i, (s, p) in enumerate(eps)]}
            for split, task, eps in tasks]
    return {"identity": {"pipeline": "bbsea", "task_group": "drawer", "policy": policy}, "values": {"tasks": rows}}


def test_detail_rows_pool_runs_per_task_and_report_progress(tmp_path):
    a = _record("cpu", [("eval", "close", [(True, 1.0), (True, 1.0)]), ("eval", "open", [(False, 0.5), (False, 0.0)])])
    b = _record("cpu", [("eval", "close", [(False, 0.25), (True, 1.0)]), ("eval", "open", [(False, 0.0), (False, 0.0)])])
    rows = detail_rows([a, b, _record("random", [("eval", "close", [(True, 1.0)]), ("eval", "open", [(False, 0.0)])])])
    group = next(r for r in rows if r["policy"] == "cpu" and r["task"] == "*")
    assert (group["k"], group["n"], group["runs"]) == (3, 8, 2)
    assert group["progress"] == pytest.approx((1 + 1 + 0.5 + 0 + 0.25 + 1 + 0 + 0) / 8)
    close = next(r for r in rows if r["policy"] == "cpu" and r["task"] == "close")
    assert (close["k"], close["n"]) == (3, 4) and close["ci"] == pytest.approx(list(wilson_interval(3, 4)))
    assert [r["policy"] for r in rows if r["task"] == "*"] == ["cpu", "random"]
    md = write_detail(rows, tmp_path / "detail")["md"].read_text()
    assert "| bbsea | drawer | cpu | eval | all tasks | 0.38 (3/8) |" in md
