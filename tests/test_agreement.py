"""Agreement statistics on hand-computable cases and on the paper's appendix tables (../shared/data)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simeval.measures.agreement.run import agreement_rows, load_score_tables
from simeval.measures.agreement.metric import (
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


def test_bootstrap_intervals_track_the_sampling_spread():
    """(Their speed is measured by experiments/benchmarks/agreement_bench.py, not here: a timed assertion fails on a
    loaded machine.)"""
    rng = np.random.default_rng(0)
    h = rng.normal(size=100)
    m = h + rng.normal(size=100)
    s = agreement_summary(h, m, n_boot=2000)
    # the Pearson interval is close to the Fisher-z interval for bivariate normal data (width ~ 2*1.96*(1-r^2)/sqrt(n))
    z = np.arctanh(s["pearson"])
    fisher = np.tanh([z - 1.96 / np.sqrt(97), z + 1.96 / np.sqrt(97)])
    assert s["pearson_ci"] == pytest.approx(list(fisher), abs=0.03)
    assert s["kendall_ci"][1] - s["kendall_ci"][0] < s["pearson_ci"][1] - s["pearson_ci"][0] + 0.05


def test_krippendorff_alpha_by_hand():
    # two units, two coders: (1,2), (3,4): D_o = (2*1/1 + 2*1/1)/4 = 1; D_e = sum over all 12 ordered pairs / 12
    x = np.array([[1, 2], [3, 4.0]])
    pooled = np.array([1, 2, 3, 4.0])
    d_e = ((pooled[:, None] - pooled[None, :]) ** 2).sum() / 12
    assert krippendorff_alpha_interval(x) == pytest.approx(1 - 1 / d_e)
    # with missing values: units {1, 2} and {3, 3, 4}; the third unit has one value and is not pairable.
    # D_o = (2/1 + 4/2) / 5 = 0.8; pooled 1, 2, 3, 3, 4: D_e = 2 * 5 * 5.2 / (5 * 4) = 2.6; alpha = 1 - 0.8/2.6
    with_missing = np.array([[1, 2, np.nan], [3, 3, 4], [np.nan, 5, np.nan]])
    assert krippendorff_alpha_interval(with_missing) == pytest.approx(1 - 0.8 / 2.6)
    assert krippendorff_alpha_interval(np.full((3, 3), 2.0)) is None


def test_icc_1_1_by_hand():
    # rows (1, 2), (3, 5): means 1.5, 4, grand 2.75; MSB = 2 * (1.25^2 + 1.25^2) / 1 = 6.25;
    # MSW = (0.25 + 0.25 + 1 + 1) / (2 * 1) = 1.25; ICC = (6.25 - 1.25) / (6.25 + 1.25) = 2/3
    assert icc_1_1(np.array([[1, 2], [3, 5.0]])) == pytest.approx(2 / 3)
    # equal target means (MSB = 0) with judges disagreeing (MSW = 16/3): ICC = -MSW / MSW = -1, not a clipped 0
    assert icc_1_1(np.array([[1, 5], [5, 1], [3, 3.0]])) == pytest.approx(-1.0)
    # incomplete rows are dropped: the NaN row changes nothing
    assert icc_1_1(np.array([[1, 2], [3, 5], [np.nan, 9.0]])) == pytest.approx(2 / 3)
    assert icc_1_1(np.full((3, 2), 4.0)) is None  # MSB = MSW = 0: undefined


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
