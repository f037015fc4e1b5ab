"""`src/generalization_tools.py variation-probe` (simeval.measures.generalization.variation_probe): which eval scenes
a variation changes, nothing trained or rolled out. Known answers: in simeval's BBSEA suite a perturbed robot start
changes every scene and a friction range none (friction is drawn after the scene, so no first observation shows it:
the knob is named); in GenSim's own piles, its unseen colours recolour separating-piles and leave
move-piles-along-line (fixed colours) as it was, and GenSim's test mode alone changes no scene (its checkout draws the
train colours in every mode)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, str(ROOT / "src" / "generalization_tools.py"), "variation-probe"]
GENSIM = ROOT.parent / "shared" / "gensim"
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src")}


def probe(out: Path, *overrides: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run([*COMMAND, "--out-dir", str(out), *overrides], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env=ENV)


def changed(out: Path, name: str) -> dict:
    rows = json.loads((out / f"eval_variation_{name}.json").read_text())["tasks"]
    return {r["task"]: (r["varied"], r["unseen_knobs"]) for r in rows}


def test_a_robot_start_changes_every_scene_and_friction_none_and_is_named(tmp_path):
    suite = ["pipeline=bbsea", "task_group=table", "tasks=[bbsea-block-in-bin]", "eval.seeds=2", "policy=tiny"]
    moved = probe(tmp_path / "robot", *suite, "eval.variation={robot: {home_noise: 0.3}}")
    assert moved.returncode == 0, moved.stderr[-2000:]
    assert changed(tmp_path / "robot", "bbsea_table") == {"bbsea-block-in-bin": ([100000, 100001], [])}
    friction = probe(tmp_path / "friction", *suite, "eval.variation={block: {friction: [0.05, 0.1]}}")
    assert friction.returncode == 0, friction.stderr[-2000:]
    assert changed(tmp_path / "friction", "bbsea_table") == {"bbsea-block-in-bin": ([], ["block.friction"])}
    table = (tmp_path / "friction" / "eval_variation_bbsea_table.md").read_text()
    assert "| bbsea-block-in-bin | `{\"block\": {\"friction\": [0.05, 0.1]}}` | 0/2 | - | block.friction |" in table
    assert "- 0 of 2 eval scenes differ" in table

    # an existing table is kept unless asked; a bad override or task is one line, exit 2, nothing written
    before = (tmp_path / "friction" / "eval_variation_bbsea_table.json").read_text()
    again = probe(tmp_path / "friction", *suite, "eval.variation={robot: {home_noise: 0.3}}")
    assert again.returncode == 2 and "already there; pass --overwrite" in again.stderr
    assert len(again.stderr.strip().splitlines()) == 1 and "Traceback" not in again.stderr
    assert (tmp_path / "friction" / "eval_variation_bbsea_table.json").read_text() == before
    for bad, says in [(["pipeline=bbsea", "task_group=table", "tasks=[no-such-task]", "policy=tiny"], "no-such-task"),
                      (["pipeline=nowhere"], "pipeline=nowhere"),
                      ([*suite, "eval.variation=[1]"], "eval.variation=[1]"),
                      ([*suite, "eval.seeds=0"], "eval.seeds must be a whole number >= 1, got 0"),
                      ([*suite, "eval.seeds=abc"], "eval.seeds='abc': expected a whole number"),
                      ([*suite, "eval.seed_offset=-3"], "eval.seed_offset must be a whole number >= 0, got -3"),
                      ([*suite, "eval.max_steps=-1"], "eval.max_steps must be a whole number >= 1, got -1")]:
        for out in (tmp_path / "bad", tmp_path / "friction"):  # the mistake is named, not "already there"
            refused = probe(out, *bad)
            assert refused.returncode == 2 and says in refused.stderr, refused.stderr[-2000:]
            assert len(refused.stderr.strip().splitlines()) == 1 and "Traceback" not in refused.stderr
        assert not (tmp_path / "bad").exists()

    # without --out-dir the tables go where paths.root puts them
    rooted = subprocess.run([*COMMAND, *suite, f"paths.root={tmp_path / 'root'}"],
                            capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert rooted.returncode == 0, rooted.stderr[-2000:]
    assert (tmp_path / "root" / "tables" / "eval_variation_bbsea_table.md").is_file()


@pytest.mark.skipif(not (GENSIM / "cliport").is_dir(), reason="../shared/gensim is not beside this checkout")
@pytest.mark.timeout(900)
def test_gensims_unseen_colours_recolour_separating_piles_only_and_its_test_mode_nothing(tmp_path):
    own = ["pipeline=gensim_own", f"pipeline.root={GENSIM}", "task_group=piles",
           "tasks=[separating-piles,move-piles-along-line]", "eval.seeds=1", "policy=tiny"]
    colours = probe(tmp_path / "colours", *own)  # the default eval variation: {mode: test, unseen_colors: true}
    assert colours.returncode == 0, colours.stderr[-2000:]
    assert changed(tmp_path / "colours", "gensim_own_piles") == {"separating-piles": ([100000], []),
                                                                 "move-piles-along-line": ([], [])}
    mode = probe(tmp_path / "mode", *own, "eval.variation={mode: test}")
    assert mode.returncode == 0, mode.stderr[-2000:]
    assert changed(tmp_path / "mode", "gensim_own_piles") == {"separating-piles": ([], []),
                                                              "move-piles-along-line": ([], [])}
