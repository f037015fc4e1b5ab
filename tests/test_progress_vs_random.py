"""`src/generalization_tools.py vs-random` (simeval.measures.generalization.vs_random): a policy's rollout progress
against the chance baseline's, by hand."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from simeval.measures.generalization import vs_random as mod

ROOT = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, str(ROOT / "src" / "generalization_tools.py"), "vs-random"]


def _run(folder: Path, rollouts: dict, policy: str = "cpu") -> Path:
    """A generalization result.json with {(task, split): [progress, ...]}."""
    tasks = [{"task": t, "split": s, "episodes": [{"seed": 100000 + i, "success": False, "progress": p}
                                                  for i, p in enumerate(ps)]} for (t, s), ps in rollouts.items()]
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps({"metric": "generalization", "identity": {"policy": policy},
                                                    "values": {"tasks": tasks}}))
    return folder


def test_the_comparison_by_hand():
    c = mod.compare([0.5, 0.7, 0.9], [0.0, 0.1, 0.2])
    assert np.isclose(c["difference"], 0.7 - 0.1) and c["n_policy"] == c["n_random"] == 3
    # every policy value above every random one: the exact one-sided p is 1 / C(6, 3) = 1/20
    assert np.isclose(c["p_one_sided"], 1 / 20)
    lo, hi = c["interval"]  # resampled means stay within the extreme differences
    assert 0.5 - 0.2 <= lo <= 0.6 <= hi <= 0.9 - 0.0
    same = mod.compare([0.3, 0.3], [0.1, 0.1])
    assert np.allclose(same["interval"], [0.2, 0.2])  # no spread in either group


def test_the_cli_pools_seeds_drops_a_task_and_refuses_a_wrong_folder_in_one_line(tmp_path):
    a = _run(tmp_path / "a", {("t1", "eval"): [0.5, 0.7], ("dup", "eval"): [0.9, 0.9], ("h", "heldout"): [0.4]})
    b = _run(tmp_path / "b", {("t1", "eval"): [0.9], ("dup", "eval"): [0.9]})
    r = _run(tmp_path / "r", {("t1", "eval"): [0.0, 0.1], ("dup", "eval"): [0.0], ("h", "heldout"): [0.0],
                               ("t1", "train"): [0.0]}, policy="random")
    out = subprocess.run([*COMMAND, "--policy", str(a), str(b), "--random", str(r),
                          "--drop-task", "dup"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    rows = {line.split("|")[1].strip(): line for line in out.stdout.splitlines()[2:] if line.startswith("|")}
    assert set(rows) == {"eval", "heldout"}
    assert "train: no row (no policy rollouts in that split)" in out.stdout  # said, not silently left out
    assert "| 0.700 (3) | 0.050 (2) | 0.65 [" in rows["eval"]  # (0.5 + 0.7 + 0.9) / 3 against (0.0 + 0.1) / 2
    (tmp_path / "wm").mkdir()  # a world-model run also has values.tasks: a list of names
    (tmp_path / "wm" / "result.json").write_text(json.dumps({"metric": "dynamics_diversity",
                                                             "values": {"tasks": ["t1"]}}))
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "result.json").write_text(json.dumps({"metric": "generalization",
                                                              "values": {"tasks": [{"task": "t1"}]}}))
    for args, said in ((["--policy", str(tmp_path / "none"), "--random", str(r)], "result.json: no such file"),
                       (["--policy", str(tmp_path / "wm"), "--random", str(r)],
                        "its metric is 'dynamics_diversity', not 'generalization'"),
                       (["--policy", str(tmp_path / "bad"), "--random", str(r)], "a rollout row without task, split"),
                       (["--policy", str(a / "result.json"), "--random", str(r)], "cannot read it (Not a directory)"),
                       (["--policy", str(a), "--random", str(b)], "is a policy=cpu run; --random takes runs of "
                                                                  "policy=random"),
                       (["--policy", str(a), "--random", str(r), "--drop-task", "dupp"],
                        "--drop-task dupp: no such task in these runs; they have dup, h, t1"),
                       (["--policy", str(b), "--random", str(r), "--drop-task", "t1", "dup"],
                        "no split has rollouts of both")):
        refused = subprocess.run([*COMMAND, *args], capture_output=True, text=True, timeout=120,
                                 cwd=ROOT)
        assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1, refused.stderr
        assert said in refused.stderr and refused.stdout == "", (said, refused.stderr)


def test_eval_rollouts_left_out_as_unvaried_are_not_counted():
    """An eval seed whose scene the variation left as the train split's was not rolled out (no progress): the
    comparison reads the others."""
    record = {"values": {"tasks": [{"task": "t1", "split": "eval", "episodes": [
        {"seed": 1, "success": False, "progress": 0.5}, {"seed": 2, "start": "0123456789abcdef", "unvaried": True}]}]}}
    assert mod.progress_values(record, "eval", set()) == [0.5]
