"""Committed artefacts are byte-reproducible and free of machine paths; `make clean` keeps the paid judge cache."""

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from simeval.measures.text_diversity.artefacts import build_text_diversity_report
from simeval.results import write_result

ROOT = Path(__file__).resolve().parents[1]
SPEC = yaml.safe_load((ROOT / "conf" / "report" / "table3.yaml").read_text())
ABSOLUTE_PATH = re.compile(r"(?<![\w.:/])/(?:work|home|tmp|Users|root|mnt|scratch|private|var|opt)/")
FIGURE3 = ["agreement.csv", "agreement.md", "agreement.tex", "figure3.png", "figure3.pdf"]


def _git(*args):
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def _runs(root, created, sha):
    values = {g: {"n": 5, "div": d, "vendi": 2.0, "cos_dist": 0.3, "self_bleu": 0.1, "div_ci": [d - 0.1, d + 0.1],
                  "subsample": {"n": 3, "div_mean": d}} for g, d in (("stacking", 0.4912345678901), ("all", 0.75))}
    for embedding in ("minilm", "mpnet"):
        path = write_result(root / "2026-01-01_00-00-00-123456_1-abc" / embedding, metric="text_diversity",
                            version="2.0", values=values, seed=0, pipeline="gensim", embedding=embedding,
                            config={"pipeline": {"grouped_file": str(root / "gensim_descs.yaml")}},
                            identity={"pipeline": "gensim", "task_group": "each", "embedding": embedding})
        rec = json.loads(path.read_text())
        path.write_text(json.dumps({**rec, "created": created, "git_sha": sha}))
    write_result(root / "x" / "bbsea", metric="text_diversity", version="2.0", values={}, status="missing",
                 pipeline="bbsea", embedding="minilm", missing_hint="set pipeline.root=... (or env BBSEA_ROOT)")


def test_table3_report_is_the_same_bytes_wherever_and_whenever_its_runs_were_made(tmp_path):
    """The same numbers in another folder, at another time, from another commit: identical committed files."""
    outs = []
    for i, (created, sha) in enumerate([("2026-01-01T00:00:00+00:00", "a" * 40),
                                        ("2027-05-05T12:00:00+00:00", "b" * 40 + "-dirty")]):
        _runs(tmp_path / f"machine{i}" / "runs", created, sha)
        out = tmp_path / f"machine{i}" / "tables"
        build_text_diversity_report(tmp_path / f"machine{i}" / "runs", out, id="table3", rows=SPEC["rows"],
                                    columns=SPEC["columns"], caption=SPEC["caption"])
        outs.append(out)
    committed = sorted(p.name for p in outs[0].iterdir() if not p.name.endswith("_sources.csv"))
    assert "table3_tidy.csv" in committed and "table3.tex" in committed
    for name in committed:
        a, b = (outs[0] / name).read_text(), (outs[1] / name).read_text()
        assert a == b, name
        assert not ABSOLUTE_PATH.search(a) and str(tmp_path) not in a and "aaaaaaaa" not in a, name
    assert "0.491235" in (outs[0] / "table3_tidy.csv").read_text()  # rounded: last-bit noise does not show
    # provenance (paths, shas, times) goes to <id>_sources.csv, which git ignores
    assert "a" * 40 in (outs[0] / "table3_sources.csv").read_text()
    assert _git("check-ignore", "-q", "outputs/tables/table3_sources.csv").returncode == 0


def test_saved_figures_carry_no_dates(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simeval.writing.figures import save_figure

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [1, 0])
    for fmt in ("png", "pdf", "svg"):
        save_figure(fig, tmp_path / "a" / f"f.{fmt}")
        time.sleep(1.1)  # PDF/SVG dates are to the second
        save_figure(fig, tmp_path / "b" / f"f.{fmt}")
        assert (tmp_path / "a" / f"f.{fmt}").read_bytes() == (tmp_path / "b" / f"f.{fmt}").read_bytes(), fmt
    assert b"CreationDate" not in (tmp_path / "a" / "f.pdf").read_bytes()
    plt.close(fig)


def test_make_figure3_reproduces_the_committed_files(shared_data, tmp_path):
    """What `make figure3` runs, into a fresh folder: the committed tables and figures, byte for byte."""
    out = tmp_path / "figure3"
    res = subprocess.run([sys.executable, str(ROOT / "src" / "agreement.py"),
                          f"scores_path={shared_data / 'human_eval_tables.json'}", f"hydra.run.dir={out}"],
                         cwd=ROOT, capture_output=True, text=True, timeout=600,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert res.returncode == 0, res.stderr[-2000:]
    for name in FIGURE3:
        assert (out / name).read_bytes() == (ROOT / "outputs" / "figures" / "figure3" / name).read_bytes(), name
    assert json.loads((out / "result.json").read_text())["figures"] == ["figure3.png", "figure3.pdf"]


def test_committed_outputs_hold_no_machine_paths_or_run_metadata():
    tracked = _git("ls-files", "outputs").stdout.split()
    assert "outputs/figures/figure3/figure3.pdf" in tracked and "outputs/tables/table3.csv" in tracked
    # 6-decimal values change in the last digit from one CPU to another: not committed (see .gitignore)
    assert "outputs/tables/table3_tidy.csv" not in tracked
    assert _git("check-ignore", "-q", "outputs/tables/table3_tidy.csv").returncode == 0
    for name in tracked:
        path = Path(name)
        assert path.name not in ("result.json", "multirun.yaml") and ".hydra" not in path.parts, name
        assert path.suffix != ".log" and not path.name.endswith("_sources.csv"), name
        data = (ROOT / path).read_bytes()
        if path.suffix == ".pdf":
            assert b"CreationDate" not in data, name
        if path.suffix in (".csv", ".md", ".tex", ".json", ".yaml"):
            text = data.decode()
            assert not ABSOLUTE_PATH.search(text) and "git_sha" not in text, name
    for produced in ("outputs/figures/figure3/.hydra/hydra.yaml", "outputs/figures/figure3/agreement.log",
                     "outputs/figures/figure3/result.json", "outputs/tables/table3_sources.csv"):
        assert _git("check-ignore", "-q", produced).returncode == 0, produced


def _make(target, cwd):
    return subprocess.run(["make", "--no-print-directory", target], cwd=cwd, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_clean_keeps_the_paid_judge_cache_and_clean_caches_says_what_it_deletes(tmp_path):
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    for d in ("outputs/runs/quality/x", "outputs/multiruns/y", "outputs/table3/runs/0", "outputs/cache"):
        (tmp_path / d).mkdir(parents=True)
    (tmp_path / "outputs/cache/judge_calls.sqlite").write_text("paid")
    (tmp_path / "outputs/cache/embeddings.sqlite").write_text("free")
    res = _make("clean", tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "outputs/cache/judge_calls.sqlite").read_text() == "paid"
    assert not (tmp_path / "outputs/runs").exists() and not (tmp_path / "outputs/table3").exists()
    assert "kept outputs/cache/ (embedding and paid judge-call caches); `make clean-caches` deletes it" in res.stdout
    res = _make("clean-caches", tmp_path)
    assert res.returncode == 0, res.stderr
    assert "deleting outputs/cache/ (judge_calls.sqlite holds paid judge calls" in res.stdout
    assert "outputs/cache/judge_calls.sqlite" in res.stdout and "outputs/cache/embeddings.sqlite" in res.stdout
    assert not (tmp_path / "outputs/cache").exists()
