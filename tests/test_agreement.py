"""Agreement statistics on hand-computable cases and on the paper's appendix tables (../shared/data)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simeval.agreement import agreement_rows, load_score_tables
from simeval.metrics.agreement import (
    agreement_summary,
    icc_1_1,
    kendall_tau_b,
    krippendorff_alpha_interval,
    mae,
    pearson,
    r_over_mae,
    spearman,
)

ROOT = Path(__file__).resolve().parents[1]


def test_hand_computable_cases():
    h, m = [1, 2, 3], [2, 4, 6]
    assert pearson(h, m) == pytest.approx(1.0)
    assert mae(h, m) == pytest.approx(2.0)
    assert r_over_mae(h, m) == pytest.approx(0.5)
    assert pearson([1, 2, 3], [3, 2, 1]) == pytest.approx(-1.0)
    assert spearman([1, 2, 3, 4], [1, 4, 9, 16]) == pytest.approx(1.0)  # monotone, not linear
    # pairs (1,2): C, (1,3): C, (2,3): D  -> tau = (2 - 1) / 3
    assert kendall_tau_b([1, 2, 3], [1, 3, 2]) == pytest.approx(1 / 3)
    assert r_over_mae([1, 2, 3], [1, 2, 3]) is None  # MAE 0: the ratio is undefined, not infinite


def test_constant_column_is_undefined_not_zero_or_crash():
    h, m = [8.2, 8.4, 5.1, 4.8], [8.0, 8.0, 8.0, 8.0]
    assert pearson(h, m) is None and spearman(h, m) is None and kendall_tau_b(h, m) is None
    assert r_over_mae(h, m) is None and mae(h, m) == pytest.approx((0.2 + 0.4 + 2.9 + 3.2) / 4)
    s = agreement_summary(h, m, n_boot=100)
    assert s["pearson"] is None and s["pearson_ci"] is None and s["mae_ci"] is not None


def test_bootstrap_ci_brackets_the_estimate():
    rng = np.random.default_rng(0)
    h = rng.normal(size=40)
    m = h + rng.normal(scale=0.5, size=40)
    s = agreement_summary(h, m, n_boot=500)
    for name in ("pearson", "mae", "spearman", "kendall"):
        lo, hi = s[f"{name}_ci"]
        assert lo <= s[name] <= hi


def test_krippendorff_and_icc():
    perfect = np.array([[1, 1, 1], [3, 3, 3], [5, 5, 5.0]])
    assert krippendorff_alpha_interval(perfect) == pytest.approx(1.0)
    assert icc_1_1(perfect) == pytest.approx(1.0)
    # two units, two coders: (1,2), (3,4): D_o = (2*1/1 + 2*1/1)/4 = 1; D_e = sum over all 12 ordered pairs / 12
    x = np.array([[1, 2], [3, 4.0]])
    pooled = np.array([1, 2, 3, 4.0])
    d_e = ((pooled[:, None] - pooled[None, :]) ** 2).sum() / 12
    assert krippendorff_alpha_interval(x) == pytest.approx(1 - 1 / d_e)
    with_missing = np.array([[1, 1, np.nan], [4, 4, 4], [np.nan, 2, np.nan]])  # last unit not pairable
    assert krippendorff_alpha_interval(with_missing) == pytest.approx(1.0)
    assert krippendorff_alpha_interval(np.full((3, 3), 2.0)) is None


def test_paper_tables(shared_data):
    tables = load_score_tables(shared_data / "human_eval_tables.json")
    rows = {(r["table"], r["pipeline"], r["judge"]): r for r in agreement_rows(tables, n_boot=200)}
    # LLaVA-1.5 always answered 8 on completion: its correlation is undefined
    assert rows[("task_completion", "RoboGen", "LLava-1.5")]["pearson"] is None
    assert rows[("task_completion", "RoboGen", "LLava-1.5")]["mae"] == pytest.approx(1.14)
    # Hand-check one cell against numpy: GPT-4 completion on RoboGen
    recs = [r for r in tables["task_completion"] if r["pipeline"] == "RoboGen"]
    h, m = np.array([r["Human"] for r in recs]), np.array([r["GPT-4"] for r in recs])
    r = rows[("task_completion", "RoboGen", "GPT-4")]
    assert r["pearson"] == pytest.approx(np.corrcoef(h, m)[0, 1])
    assert r["r_over_mae"] == pytest.approx(np.corrcoef(h, m)[0, 1] / np.abs(h - m).mean())
    # the paper: GPT-4V is the best completion judge on RoboGen; caption+GPT-4 beats direct VLMs there for alignment
    assert r["r_over_mae"] > 0.4
    assert rows[("scene_alignment", "RoboGen", "GPT-4+Blip2")]["r_over_mae"] > rows[
        ("scene_alignment", "RoboGen", "LLava")]["r_over_mae"]


def test_agreement_entrypoint_writes_figure3(shared_data, tmp_path):
    res = subprocess.run([sys.executable, str(ROOT / "src" / "agreement.py"),
                          f"scores_path={shared_data / 'human_eval_tables.json'}", "n_boot=100", "logger=wandb",
                          f"hydra.run.dir={tmp_path}"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (tmp_path / "figure3.png").stat().st_size > 10_000 and (tmp_path / "figure3.pdf").is_file()
    rec = json.loads((tmp_path / "result.json").read_text())
    assert rec["metric"] == "agreement" and len(rec["values"]) == 27
    assert "undefined" in (tmp_path / "agreement.md").read_text()
    assert list(tmp_path.glob("wandb/offline-run-*/run-*.wandb"))  # mirrored to an offline W&B run


def test_bad_score_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_score_tables(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(ValueError, match="cannot parse"):
        load_score_tables(bad)
    csvf = tmp_path / "s.csv"
    csvf.write_text("table,pipeline,task,Human,J\nt,p,a,1,2\nt,p,b,2,x\n")
    with pytest.raises(ValueError, match="not a number: 'x'"):
        agreement_rows(load_score_tables(csvf), n_boot=10)
