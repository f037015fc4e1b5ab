"""`src/generalization_tools.py eval-vs-train` (simeval.measures.generalization.eval_vs_train): the eval split
against the train split on the same tasks and seeds, by hand."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from simeval.measures.generalization import eval_vs_train as mod

ROOT = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, str(ROOT / "src" / "generalization_tools.py"), "eval-vs-train"]


def _record(rows: dict, seed: int = 0, variation: str = "own") -> dict:
    """{(task, split): [(seed, progress or None for an unvaried seed), ...]} as a generalization result.json of
    training seed `seed`."""
    tasks = [{"task": t, "split": s, "episodes": [{"seed": seed, "start": "0" * 16, "unvaried": True} if p is None
                                                  else {"seed": seed, "success": p == 1.0, "progress": p}
                                                  for seed, p in eps]} for (t, s), eps in rows.items()]
    return {"metric": "generalization", "values": {"tasks": tasks},
            "identity": {"pipeline": "bbsea", "policy": "cpu", "seed": seed, "variations": {"a": variation}}}


def test_the_paired_gap_by_hand():
    g = mod.gap([0.0] * 5, [0.1, 0.2, 0.3, 0.4, 0.5])
    assert np.isclose(g["gap"], 0.3) and g["n"] == 5 and np.isclose(g["eval_mean"], 0.3)
    # five positive differences of distinct size: the exact two-sided signed-rank p is 2 / 2^5
    assert np.isclose(g["p_two_sided"], 2 / 32)
    lo, hi = g["interval"]  # resampled means stay within the extreme differences
    assert 0.1 <= lo <= 0.3 <= hi <= 0.5
    same = mod.gap([0.2, 0.4], [0.2, 0.4])
    assert same["gap"] == 0.0 and same["interval"] == [0.0, 0.0] and same["p_two_sided"] is None


def test_pairs_match_task_and_seed_and_skip_unvaried_and_dropped_tasks():
    record = _record({("a", "train"): [(1, 0.2), (2, 0.6), (3, 0.0)], ("a", "eval"): [(3, 1.0), (1, None), (2, 0.1)],
                      ("b", "train"): [(1, 0.5)], ("b", "eval"): [(1, 0.0)], ("c", "eval"): [(1, 0.3)]})
    assert mod.paired_progress(record, set()) == [("a", 3, 0.0, 1.0), ("a", 2, 0.6, 0.1), ("b", 1, 0.5, 0.0)]
    assert mod.paired_progress(record, {"b"}) == [("a", 3, 0.0, 1.0), ("a", 2, 0.6, 0.1)]


def test_the_cli_pools_runs_and_refuses_what_it_cannot_pair_in_one_line(tmp_path):
    for name, rows, seed, variation in (("s0", {("a", "train"): [(1, 0.0)], ("a", "eval"): [(1, 0.5)]}, 0, "own"),
                                        ("s1", {("a", "train"): [(1, 0.2)], ("a", "eval"): [(1, 0.2)]}, 1, "own"),
                                        ("other", {("a", "train"): [(1, 0.2)], ("a", "eval"): [(1, 0.2)]}, 2, "robot"),
                                        ("unpaired", {("a", "train"): [(1, 0.2)], ("a", "eval"): [(1, None)]}, 0,
                                         "own")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "result.json").write_text(json.dumps(_record(rows, seed, variation)))
    out = subprocess.run([*COMMAND, str(tmp_path / "s0"), str(tmp_path / "s1")],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert "| all | 2 | 0.100 | 0.350 | +0.250 [" in out.stdout and "| a | 2 |" in out.stdout
    for args, said in (([str(tmp_path / "unpaired")], "every eval rollout of these runs (1) was left out as unvaried"),
                       ([str(tmp_path / "s0"), str(tmp_path / "other")],
                        "another setting than {} (differs in variations.a ('own' vs 'robot'))".format(tmp_path / "s0")),
                       ([str(tmp_path / "s0"), str(tmp_path / "s0") + "/"], "given twice"),
                       ([str(tmp_path / "s0"), str(tmp_path / "unpaired")], "two runs of training seed 0"),
                       ([str(tmp_path / "s0"), "--drop-task", "b"], "--drop-task b: no such task in these runs"),
                       ([str(tmp_path / "none")], "result.json: no such file")):
        refused = subprocess.run([*COMMAND, *args], capture_output=True, text=True, timeout=120,
                                 cwd=ROOT)
        assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1, refused.stderr
        assert said in refused.stderr and refused.stdout == "", (said, refused.stderr)
