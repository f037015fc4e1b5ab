"""The validity control (simeval.measures.dynamics_diversity.controls.synthetic; experiments/world_model_control.py): a
group of tasks with k distinct dynamics must get a higher world-model error at 10 episodes per task and a larger 10 ->
40 drop than a group whose tasks share one dynamics (same colours, same starts, same actions). Tiny preset, 6 epochs,
one seed (~1 min on 2 cores); the experiment runs seeds 0 and 1 and 10/20/40 episodes."""

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


def test_replot_draws_the_figure_from_the_saved_json_alone(tmp_path):
    import subprocess
    import sys

    script = ROOT / "experiments" / "world_model_control.py"
    saved = ROOT / "outputs" / "tables" / "world_model_control.json"
    ok = subprocess.run([sys.executable, str(script), "--replot", "--out", str(saved), "--figure",
                         str(tmp_path / "f.png")], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and (tmp_path / "f.png").read_bytes() == (
        ROOT / "outputs" / "figures" / "world_model_control.png").read_bytes(), ok.stderr
    bad = subprocess.run([sys.executable, str(script), "--replot", "--out", str(tmp_path / "none.json"), "--figure",
                          str(tmp_path / "g.png")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    assert f"--replot: cannot read {tmp_path / 'none.json'}" in bad.stderr and not (tmp_path / "g.png").exists()
    (tmp_path / "edited.json").write_text("{}")
    edited = subprocess.run([sys.executable, str(script), "--replot", "--out", str(tmp_path / "edited.json"),
                             "--figure", str(tmp_path / "g.png")], capture_output=True, text=True, timeout=120)
    assert edited.returncode == 2 and "is not a table this control wrote (KeyError" in edited.stderr
    (tmp_path / "f.png").write_bytes(b"another figure")
    kept = subprocess.run([sys.executable, str(script), "--replot", "--out", str(saved), "--figure",
                           str(tmp_path / "f.png")], capture_output=True, text=True, timeout=120)
    assert kept.returncode == 2 and "exists and would change; add --overwrite" in kept.stderr
    assert (tmp_path / "f.png").read_bytes() == b"another figure"


def test_a_run_refuses_before_training_to_replace_the_committed_table_and_figure(tmp_path):
    import subprocess
    import sys

    script = ROOT / "experiments" / "world_model_control.py"
    table, figure = ROOT / "outputs" / "tables" / "world_model_control.json", \
        ROOT / "outputs" / "figures" / "world_model_control.png"
    before = table.read_bytes(), figure.read_bytes()
    for elsewhere in ([], ["--figure", str(tmp_path / "f.png")], ["--out", str(tmp_path / "t.json")]):
        r = subprocess.run([sys.executable, str(script), "--epochs", "1", *elsewhere], capture_output=True, text=True,
                           timeout=120)
        named = {"--out": f"{figure} is a committed result and this run would replace it",
                 "--figure": f"{table} is a committed result and this run would replace it"}.get(
            elsewhere[0] if elsewhere else None, f"{table} and {figure} are committed results and this run would "
                                                 "replace them")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert f"{named}; add --overwrite" in r.stderr
    assert (table.read_bytes(), figure.read_bytes()) == before and not list(tmp_path.iterdir())
    elsewhere = ["--out", str(tmp_path / "t.json"), "--figure", str(tmp_path / "f.png")]
    for bad, said in ((["--preset", "bogus"], "--preset bogus: no conf/world_model/bogus.yaml; one of cpu, paper, tiny"),
                      (["--tasks", "1"], "--tasks 1: must be >= 2"),
                      (["--episodes", "10", "50"], "episodes per task between 1 and 40"),
                      (["--out", str(tmp_path)], "is a folder; give the JSON file to write"),
                      (["--figure", str(tmp_path / "f.xyz")], "f.xyz: give a file ending in one of "),
                      (["--out", f"{script}/t.json"], f"{script} is a file, not a folder"),
                      (["--steps", "3", "--epochs", "1", "--seeds", "0", "--episodes", "10"],
                       "world_model.window.length=8: 4 of 4 tasks have no training episode that holds a window")):
        r = subprocess.run([sys.executable, str(script), *elsewhere, *bad], capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 2 and said in r.stderr and "Traceback" not in r.stderr, (bad, r.stderr)
    assert not list(tmp_path.iterdir())  # refused before anything was trained or written
