"""The notebooks' code cells run headless, in order, against the current library (so they cannot rot): quickstart
as it is, analysis against results folders made for real by the entrypoints (conftest: world_model_runs, a tiny
world model per synthetic group and episode count; policy_run, a tiny policy trained and rolled out in the
simulator)."""

import json
import math
import shutil
from pathlib import Path

import pytest
from scipy import stats

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
TESTED = {"quickstart.ipynb", "analysis.ipynb"}  # each has its test below


def run_notebook(name: str) -> dict:
    """Execute the code cells of notebooks/<name> in one namespace, as a kernel would; returns the namespace."""
    path = next(p for p in NOTEBOOKS if p.name == name)
    namespace: dict = {}
    for cell in json.loads(path.read_text())["cells"]:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), path.name, "exec"), namespace)  # noqa: S102
    return namespace


def test_every_notebook_has_a_test():
    # An empty folder would test nothing; a new notebook that no test runs would rot unseen.
    assert {p.name for p in NOTEBOOKS} == TESTED


def test_quickstart_runs(capsys):
    run_notebook("quickstart.ipynb")
    out = capsys.readouterr().out
    assert "div=" in out and "success: True" in out and "undefined, not 0" in out


def _png_size(path: Path) -> tuple[int, int]:
    from PIL import Image

    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    with Image.open(path) as im:
        return im.size


def test_analysis_on_world_model_runs_only_draws_table4_and_says_why_table5_is_missing(world_model_runs, tmp_path,
                                                                                      monkeypatch, capsys):
    results = tmp_path / "results"
    shutil.copytree(world_model_runs, results)
    monkeypatch.setenv("SIMEVAL_RESULTS", str(results))
    monkeypatch.delenv("SIMEVAL_FIGURES", raising=False)
    ns = run_notebook("analysis.ipynb")
    out = capsys.readouterr().out
    recs = {str(p): json.loads(p.read_text()) for p in results.rglob("result.json")}
    assert len(recs) == 6  # 2 groups x 3 episode counts
    df = ns["df"]
    assert df.shape == (6, 15) and "DataFrame of 6 rows x 15 columns" in out
    for path, rec in recs.items():  # each row holds its run's headline number
        row = df[df.path == path].iloc[0]
        assert (row.metric, row.pipeline, row.group, row.episodes, row.model) == (
            "dynamics_diversity", "gensim", rec["identity"]["task_group"], rec["identity"]["episodes"], "tiny")
        assert row.value == rec["values"]["eval"]["image_error"]
        assert row.per_pixel == pytest.approx(row.value / (16 * 16 * 3))
    # the Table 4 pivot: group x episodes, one seed each, so the mean is the run's own number
    for rec in recs.values():
        ident = rec["identity"]
        assert ns["pivot"].loc[("gensim", ident["task_group"], "tiny"), ident["episodes"]] == pytest.approx(
            rec["values"]["eval"]["image_error"])
    assert "115.0 / —" in out  # the paper's Table 4 value (GenSim stacking, 10 episodes) where we did not run
    figure = results / "analysis" / "table4.png"
    assert f"figure: {figure}" in out
    w, h = _png_size(figure)
    assert w > 800 and h > 300
    assert figure.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"
    assert (f"No generalization results under {results}: the success-with-intervals figure is skipped "
            "(make table5 or src/generalization.py makes them).") in out
    assert not (results / "analysis" / "table5.png").exists()


def test_analysis_with_a_policy_run_draws_success_with_wilson_intervals(world_model_runs, policy_run, tmp_path,
                                                                        monkeypatch, capsys):
    results = tmp_path / "results"
    shutil.copytree(world_model_runs, results)
    shutil.copytree(policy_run, results / "table5" / "stacking")
    figures = tmp_path / "figures"
    monkeypatch.setenv("SIMEVAL_RESULTS", str(results))
    monkeypatch.setenv("SIMEVAL_FIGURES", str(figures))
    ns = run_notebook("analysis.ipynb")
    out = capsys.readouterr().out
    df = ns["df"]
    assert df.shape == (7, 15) and (df.metric == "generalization").sum() == 1
    rec = json.loads((results / "table5" / "stacking" / "result.json").read_text())
    row = df[df.metric == "generalization"].iloc[0]
    assert (row.pipeline, row.group, row.model) == ("gensim", "stacking", "tiny")
    printed = ns["ran"].set_index("split")
    z = stats.norm.ppf(0.975)
    for split in ("train", "eval"):
        s = rec["values"]["splits"][split]["success"]
        got = printed.loc[split]
        assert (got.k, got.n, got.paper) == (s["k"], s["n"], 0.15)  # the paper's GenSim stacking value beside ours
        # a Wilson bound is a root of (k/n - p)^2 = z^2 p (1 - p) / n (the score test at 95%)
        for bound in (got.ci_low, got.ci_high):
            assert math.isclose((s["k"] / s["n"] - bound) ** 2, z * z * bound * (1 - bound) / s["n"], abs_tol=1e-9)
        assert got.ci_low <= got.rate <= got.ci_high and got.ci_high > got.ci_low
    assert "Table 5, success per group and split:" in out and "No generalization results" not in out
    for name in ("table4", "table5"):
        assert f"figure: {figures / name}.png" in out
        w, h = _png_size(figures / f"{name}.png")
        assert w > 800 and h > 300
        assert (figures / f"{name}.pdf").read_bytes()[:5] == b"%PDF-"
