"""`make evaluate PIPELINE=robogen` at the quick profile (experiments/paper.py): every stage runs as a user would
type it, the tables and the HTML report are rebuilt from the runs' result.json files, and a rerun resumes."""

import csv
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_profile_runs_one_pipeline_end_to_end_and_resumes(tmp_path):
    out = tmp_path / "paper"
    cmd = [sys.executable, str(ROOT / "experiments" / "paper.py"), "--profile", "quick", "--pipelines", "robogen",
           "--out", str(out)]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    rows = {r["group"]: r for r in csv.DictReader((out / "tables" / "table4.csv").open()) if r["pipeline"] == "robogen"}
    assert set(rows) == {"table_top", "ground"}
    for r in rows.values():  # a world model per (group, 1/2/4 episodes), beside the paper's 10/20/40 values
        assert [r["episodes_10"], r["episodes_20"], r["episodes_40"]] == ["1", "2", "4"]
        assert all(float(r[f"ours_{k}"]) > 0 for k in (10, 20, 40)) and r["preset"] == "tiny"
    t5 = {r["Task group"]: r for r in csv.DictReader((out / "tables" / "table5.csv").open())
          if r["Pipeline"] == "robogen"}
    assert t5["table_top"]["Runs"] == "1" and t5["ground"]["Runs"] == "1" and t5["ground"]["Policy"] == "tiny"
    html = (out / "report" / "index.html").read_text()
    assert "table4/robogen/ground/episodes_4" in html and "generalization" in html
    again = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0
    assert "diversity.py" not in again.stdout and "generalization.py" not in again.stdout  # finished stages skipped
