"""Table 5's honest companions: the task-level (cluster) bootstrap interval of a group's rate against its normal
approximation, the random-policy baseline's actions, and the per-task detail table from hand-built records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simeval.stats.intervals import task_bootstrap_interval, wilson_interval
from simeval.measures.generalization.random_baseline import RandomActions
from simeval.measures.generalization.table5 import detail_lines, detail_rows, write_detail

ROOT = Path(__file__).resolve().parents[1]


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


def test_seed_and_task_bootstrap_reduces_to_the_task_bootstrap_for_identical_seeds():
    k, n = [5, 0, 1, 0, 2, 0], [5, 5, 5, 5, 5, 5]
    one = task_bootstrap_interval(k, n)
    assert task_bootstrap_interval([k], [n]) == one  # one seed: the (T,) interval exactly
    assert task_bootstrap_interval([k, k, k], [n, n, n]) == one  # identical seeds add nothing


def test_seed_spread_alone_widens_the_interval_by_hand():
    """Two tasks of equal rate inside each seed, seeds 0.5 and 0.0 apart: resampling tasks alone sees no spread
    ([0.25, 0.25]); resampling the two seeds gives 0 (both seed 1), 0.25 (one each, p = 1/2) or 0.5 (both seed 0)."""
    k, n = [[2, 2], [0, 0]], [[4, 4], [4, 4]]
    assert task_bootstrap_interval(np.sum(k, 0), np.sum(n, 0)) == (0.25, 0.25)
    assert task_bootstrap_interval(k, n, n_boot=2000) == (0.0, 0.5)


def test_seed_and_task_bootstrap_matches_exact_enumeration():
    """2 seeds x 3 tasks: all 2^2 * 3^3 = 108 equally likely (seed draw, task draw) pairs enumerated, the pooled rate
    of each; the bootstrap's 2.5% / 97.5% quantiles must land on the exact distribution's quantiles (chosen where its
    CDF does not sit on 0.025 or 0.975, so a large bootstrap cannot fall between two support points)."""
    import itertools

    k = np.array([[3, 0, 1], [1, 0, 2]])
    n = np.full((2, 3), 4)
    rates = []
    for seeds in itertools.product(range(2), repeat=2):
        for tasks in itertools.product(range(3), repeat=3):
            rates.append(sum(k[s, t] for s in seeds for t in tasks) / sum(n[s, t] for s in seeds for t in tasks))
    values = np.unique(rates)
    cdf = np.array([np.mean(np.array(rates) <= v) for v in values])  # P(rate <= v) over the 108 draws
    exact = []
    for q in (0.025, 0.975):
        i = int(np.searchsorted(cdf, q))  # the smallest support point whose CDF reaches q
        below = cdf[i - 1] if i else 0.0
        assert cdf[i] - q > 0.004 and q - below > 0.004  # q is inside a step, not on its edge
        exact.append(values[i])
    lo_exact, hi_exact = exact
    lo, hi = task_bootstrap_interval(k, n, n_boot=40000)
    assert (lo, hi) == pytest.approx((lo_exact, hi_exact))


def test_task_bootstrap_refuses_mismatched_shapes():
    from simeval.errors import UserError

    with pytest.raises(UserError, match="one shape"):
        task_bootstrap_interval([[1, 2]], [[3, 3], [3, 3]])


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


def _record(policy: str, tasks: list[tuple[str, str, list[tuple[bool, float]]]], seed: int = 0) -> dict:
    rows = [{"split": split, "task": task,
             "success": {"k": sum(s for s, _ in eps), "n": len(eps)},
             "episodes": [{"seed": i, "success": s, "progress": p, "steps": 1} for i, (s, p) in enumerate(eps)]}
            for split, task, eps in tasks]
    return {"identity": {"pipeline": "bbsea", "task_group": "drawer", "policy": policy, "seed": seed},
            "values": {"tasks": rows}, "path": f"runs/{policy}/{seed}/result.json"}


def test_detail_rows_pool_runs_per_task_and_report_progress(tmp_path):
    a = _record("cpu", [("eval", "close", [(True, 1.0), (True, 1.0)]), ("eval", "open", [(False, 0.5), (False, 0.0)])])
    b = _record("cpu", [("eval", "close", [(False, 0.25), (True, 1.0)]), ("eval", "open", [(False, 0.0), (False, 0.0)])],
                seed=1)
    rows = detail_rows([a, b, _record("random", [("eval", "close", [(True, 1.0)]), ("eval", "open", [(False, 0.0)])])])
    group = next(r for r in rows if r["policy"] == "cpu" and r["task"] == "*")
    assert (group["k"], group["n"], group["runs"]) == (3, 8, 2)
    assert group["progress"] == pytest.approx((1 + 1 + 0.5 + 0 + 0.25 + 1 + 0 + 0) / 8)
    close = next(r for r in rows if r["policy"] == "cpu" and r["task"] == "close")
    assert (close["k"], close["n"]) == (3, 4) and close["ci"] == pytest.approx(list(wilson_interval(3, 4)))
    assert [r["policy"] for r in rows if r["task"] == "*"] == ["cpu", "random"]
    md = write_detail(detail_lines(rows), tmp_path / "detail")["md"].read_text()
    assert "| bbsea | drawer | cpu | eval | all tasks | 0.38 (3/8) |" in md
    assert group["run_rates"] == {0: 0.5, 1: 0.25}  # seed 0: 2 of 4, seed 1: 1 of 4
    assert group["task_ci"] == task_bootstrap_interval([[2, 0], [1, 0]], [[2, 2], [2, 2]])
    assert group["run_progress"] == pytest.approx({0: (1 + 1 + 0.5 + 0) / 4, 1: (0.25 + 1 + 0 + 0) / 4})
    assert "seed 0: 0.50 (progress 0.62), seed 1: 0.25 (progress 0.31)" in md
    # runs launched side by side can sort seed 2 before seed 1 by folder; the table lists them by seed
    late = [_record("cpu", [("eval", "close", [(i == 2, 1.0)])], seed=i) for i in (0, 2, 1)]
    late_md = write_detail(detail_lines(detail_rows(late)), tmp_path / "late")["md"].read_text()
    assert ("seed 0: 0.00 (progress 1.00), seed 1: 0.00 (progress 1.00), seed 2: 1.00 (progress 1.00)"
            in late_md)


def test_the_committed_detail_reads_back_as_written_and_a_rerun_group_replaces_its_lines(tmp_path):
    """table5_detail.csv read back and written again gives the committed bytes (CSV, Markdown, LaTeX); merging
    fresh lines of one (pipeline, group, policy) replaces exactly that group's lines and keeps the others, in
    the order detail_rows gives (the paper's groups first, then by policy)."""
    from simeval.measures.generalization.table5 import merge_detail, read_detail_lines

    committed = ROOT / "outputs" / "tables" / "table5_detail"
    kept = read_detail_lines(committed.with_suffix(".csv"))
    written = write_detail(kept, tmp_path / "again")
    for suffix in ("csv", "md", "tex"):
        assert written[suffix].read_bytes() == committed.with_suffix(f".{suffix}").read_bytes(), suffix
    fresh = detail_lines(detail_rows([_record("cpu", [("eval", "close", [(True, 1.0)])])]))  # bbsea/drawer/cpu
    merged = merge_detail(kept, fresh)
    assert [c for c in merged if c[:3] == ["bbsea", "drawer", "cpu"]] == fresh
    assert [c for c in merged if c[:3] != ["bbsea", "drawer", "cpu"]] == [c for c in kept
                                                                           if c[:3] != ["bbsea", "drawer", "cpu"]]
    new_group = [["mypipeline", "mygroup", *c[2:]] for c in fresh]
    assert merge_detail(kept, new_group)[-len(new_group):] == new_group  # not a paper group: after them


def test_a_rebuild_with_keep_keeps_the_committed_per_task_table_beside_the_new_group(tmp_path):
    """rebuild_table5(keep=[table5.csv]) also keeps the table5_detail.csv beside it: every committed detail line
    stays, and the new run's group (not one of the paper's) follows them."""
    import json

    from simeval.measures.generalization.table5 import METRIC, rebuild_table5

    run = _record("cpu", [("eval", "reach", [(True, 1.0), (False, 0.5)])])
    run["identity"].update(pipeline="mypipeline", task_group="mygroup")  # a group the committed table lacks
    run["values"]["splits"] = {"eval": {"success": {"k": 1, "n": 2}}}
    (tmp_path / "runs" / "0").mkdir(parents=True)
    (tmp_path / "runs" / "0" / "result.json").write_text(json.dumps({"metric": METRIC, "status": "ok", **run}))
    rebuild_table5(tmp_path / "runs", tmp_path / "t5", tmp_path / "t5.png",
                   keep=[ROOT / "outputs" / "tables" / "table5.csv"])
    committed = (ROOT / "outputs" / "tables" / "table5_detail.csv").read_text().splitlines()
    rebuilt = (tmp_path / "t5_detail.csv").read_text().splitlines()
    assert rebuilt[: len(committed)] == committed
    assert rebuilt[len(committed):] == [
        'mypipeline,mygroup,cpu,eval,all tasks,0.50 (1/2),"[0.09, 0.91]",-,-,0.75,1',
        'mypipeline,mygroup,cpu,eval,reach,0.50 (1/2),"[0.09, 0.91]",-,-,0.75,1']
    # a per-task table beside a kept one that is cut short fails before any work, naming the key and the file
    from simeval.errors import UserError
    from simeval.writing.tables import ReportWords

    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "table5.csv").write_text((ROOT / "outputs" / "tables" / "table5.csv").read_text())
    (tmp_path / "kept" / "table5_detail.csv").write_text("\n".join(committed[:3] + [committed[3][:20]]) + "\n")
    with pytest.raises(UserError, match="^report.keep: .*table5_detail.csv, line 4: "):
        rebuild_table5(tmp_path / "runs", tmp_path / "t5b", tmp_path / "t5b.png",
                       keep=[tmp_path / "kept" / "table5.csv"], words=ReportWords(keep="report.keep"))
    assert not (tmp_path / "t5b.csv").exists()


def test_two_runs_of_one_seed_are_refused_not_pooled_twice():
    from simeval.errors import UserError
    from simeval.measures.generalization.table5 import build

    a = _record("cpu", [("eval", "close", [(True, 1.0)])])
    b = dict(a, path="elsewhere/result.json")
    with pytest.raises(UserError, match="seed 0"):
        build([a, b])


def test_rollouts_left_out_as_unvaried_count_nowhere():
    """Eval rollouts whose scene the variation left as the train split's (evaluate.rollout_task's unvaried) are not
    rolled out: Table 5 and its detail count the others, and a group where none changed has no eval cell."""
    from simeval.measures.generalization.table5 import build

    def record(seed, eval_episodes):
        rec = _record("cpu", [("train", "a", [(True, 1.0), (False, 0.5)])], seed=seed)
        done = [e for e in eval_episodes if not e.get("unvaried")]
        rec["values"]["tasks"].append({"split": "eval", "task": "a", "episodes": eval_episodes,
                                       "success": {"k": sum(e["success"] for e in done), "n": len(done)}})
        rec["values"]["splits"] = {
            "train": {"success": {"k": 1, "n": 2}, "mean_progress": 0.75},
            "eval": {"success": {"k": sum(e["success"] for e in done), "n": len(done)},
                     "mean_progress": float(np.mean([e["progress"] for e in done])) if done else None,
                     "unvaried": len(eval_episodes) - len(done)}}
        return rec

    unvaried = {"seed": 1, "start": "0123456789abcdef", "unvaried": True}
    ran = {"seed": 0, "start": "fedcba9876543210", "success": True, "progress": 1.0, "steps": 3}
    (row,) = [r for r in build([record(0, [ran, unvaried]), record(1, [unvaried, unvaried])])
              if r["pipeline"] == "bbsea" and r["group"] == "drawer" and r["runs"]]
    assert (row["eval"]["k"], row["eval"]["n"], row["eval_progress"]) == (1, 1, 1.0)
    lines = [r for r in detail_rows([record(0, [ran, unvaried]), record(1, [unvaried, unvaried])])
             if r["split"] == "eval"]
    assert [(r["task"], r["k"], r["n"], r["progress"]) for r in lines] == [("*", 1, 1, 1.0), ("a", 1, 1, 1.0)]
    assert lines[0]["run_rates"] == {0: 1.0, 1: None}
    (row,) = [r for r in build([record(0, [unvaried])]) if r["pipeline"] == "bbsea" and r["group"] == "drawer"
              and r["runs"]]
    assert row["eval"] is None and row["eval_progress"] is None and row["train"]["n"] == 2
    assert not [r for r in detail_rows([record(0, [unvaried])]) if r["split"] == "eval"]
