"""The HTML report built from real runs: a quality sweep judged by a loopback VLM (one task with a video, one whose
judge replies are unparseable), an oracle run, and a table and figure. The page is parsed and every img/src,
video/src and a/href must resolve to a file inside the report folder; the gallery must show the judge's replies
and what it saw. When Chromium is installed, the page is also rendered headless to a screenshot."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np
import pytest

from helpers import make_bundles

ROOT = Path(__file__).resolve().parents[1]


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[tuple[str, str, str]] = []  # (tag, attribute, value)
        self.text: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k == "id":
                self.ids.add(v)
            if (tag, k) in (("img", "src"), ("video", "src"), ("source", "src"), ("a", "href"), ("link", "href")):
                self.refs.append((tag, k, v))

    def handle_data(self, data):
        self.text.append(data)


def _run(script: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in __import__("os").environ.items()}
    env["PYTHONPATH"] = str(ROOT / "src")
    return subprocess.run([sys.executable, str(ROOT / "src" / script), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600, env=env)


def _reply_by_task(payload) -> str:
    """task0 scores high, task1 low (and its completion replies are unparseable), task2 in the middle."""
    text = json.dumps(payload)
    if "block 1 " in text:
        return "The stack is not there at all." if "complet" in text.lower() else "Score: 1"
    return "Score: 5" if "block 0 " in text else "Score: 3"


@pytest.fixture
def report_inputs(openai_server, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    bundles = make_bundles(tmp_path / "bundles", n=3, video="task2")
    openai_server.default_reply = _reply_by_task
    sweep = work / "sweep"
    res = _run("quality.py", "-m", f"bundles_dir={bundles}", f"judge.provider.base_url={openai_server.base_url}",
               "debug=tiny", "label=GenSim-test", f"cache_dir={tmp_path / 'cache'}", "seed=0,1",
               f"hydra.sweep.dir={sweep}", cwd=work)
    # every task fails in neither run: exit 0; task1's completion has no valid score
    assert res.returncode == 0, res.stderr[-3000:]
    res = _run("quality.py", f"bundles_dir={bundles}", "judge=oracle", f"hydra.run.dir={sweep / 'oracle'}", cwd=work)
    assert res.returncode == 0, res.stderr[-3000:]
    tables, figures = work / "tables", work / "figures"
    res = _run("report.py", "report=figure4", f"report.runs_dir={sweep}", f"report.out_dir={figures}", cwd=work)
    assert res.returncode == 0, res.stderr[-3000:]
    (tables / "notes").mkdir(parents=True)
    shutil.copy(figures / "figure4.md", tables / "figure4.md")
    shutil.copy(figures / "figure4.csv", tables / "figure4.csv")
    return work, sweep, tables, figures, bundles


def test_html_report_links_resolve_and_gallery_shows_replies(report_inputs, tmp_path):
    work, sweep, tables, figures, bundles = report_inputs
    res = _run("report.py", "report=html", f"report.runs_dir={sweep}", f"report.tables_dir={tables}",
               f"report.figures_dir={figures}", cwd=work)
    assert res.returncode == 0, res.stderr[-3000:]
    page = sweep / "report" / "index.html"
    assert str(page) in res.stdout
    # the report folder is self-contained: move it away from the runs and the bundles, then resolve every link
    moved = tmp_path / "elsewhere" / "report"
    shutil.copytree(page.parent, moved)
    shutil.rmtree(bundles)
    parser = _Links()
    parser.feed((moved / "index.html").read_text(encoding="utf-8"))
    refs = parser.refs
    kinds = {(t, a) for t, a, _ in refs}
    assert ("img", "src") in kinds and ("video", "src") in kinds and ("a", "href") in kinds
    for tag, attr, value in refs:
        if value.startswith("#"):
            assert value[1:] in parser.ids, f"{tag} {attr}={value}: no such anchor"
            continue
        url = urlparse(value)
        assert not url.scheme and not url.netloc and not value.startswith("/"), f"{tag} {attr}={value} not relative"
        target = (moved / unquote(url.path)).resolve()
        assert target.is_file(), f"{tag} {attr}={value} does not resolve"
        assert moved.resolve() in target.parents, f"{value} points outside the report folder"
    text = " ".join(parser.text)
    # 2 sweep jobs + the oracle run; each run's record is linked
    assert sum(v.endswith("record.json") for _, _, v in refs) == 3
    # the judge's unparseable replies are on the page with the parse error, for the low-scoring task
    assert "The stack is not there at all." in text and "no 'Score: X' in reply" in text
    assert "stack block 1 on the pallet" in text
    # the simulator's verdict beside the judge's (make_bundles: task1 progress 0.5)
    assert "progress: 0.50 (oracle completion 5.0 / 10)" in text
    # what the judge saw: 4 scene views and (debug=tiny: n_frames=2) 2 frames per task, per judged run
    imgs = [v for t, _, v in refs if t == "img"]
    per_run = [v for v in imgs if "/quality/0/" in v]
    assert sum("/scene/" in v for v in per_run) == 3 * 4 and sum("/frames/" in v for v in per_run) == 3 * 2
    assert any(v.endswith("figure4.png") for v in imgs)
    # the lowest-scoring task comes first in each judged run's gallery
    html_text = (moved / "index.html").read_text(encoding="utf-8")
    first = html_text.index("id='task-0-task1'")
    assert first < html_text.index("id='task-0-task2'") < html_text.index("id='task-0-task0'")
    # the table is rendered as a table, with its csv linked
    assert "GenSim-test" in text and any(v.endswith("figure4.csv") for _, _, v in refs)
    # a report inside runs_dir does not report on itself; copies are never named result.json
    assert not list(moved.rglob("result.json"))
    again = _run("report.py", "report=html", f"report.runs_dir={sweep}", f"report.tables_dir={tables}",
                 f"report.figures_dir={figures}", cwd=work)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "Runs (3)" in page.read_text(encoding="utf-8")
    # bundles gone: the page still builds and says so, with the replies
    assert "is not there any more" in page.read_text(encoding="utf-8")

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        return  # the parse-and-resolve checks above are the test; the browser is extra where one is installed
    shot = tmp_path / "screenshot.png"
    r = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                        f"--screenshot={shot}", "--window-size=1280,2400", (moved / "index.html").as_uri()],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and shot.is_file() and shot.stat().st_size > 10_000, r.stderr[-2000:]


def test_missing_runs_dir_is_one_line(tmp_path):
    res = _run("report.py", "report=html", f"report.runs_dir={tmp_path / 'nope'}", cwd=tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip() == (f"error: report.runs_dir={str(tmp_path / 'nope')!r} is not a folder: give a run or "
                                  "sweep folder (e.g. outputs/runs or outputs/multiruns/quality/<time>)")


def test_an_assets_folder_that_is_not_a_reports_is_never_deleted(tmp_path):
    runs, out = tmp_path / "runs", tmp_path / "site"
    runs.mkdir()
    (out / "assets").mkdir(parents=True)
    (out / "assets" / "logo.png").write_bytes(b"mine")
    res = _run("report.py", "report=html", f"report.runs_dir={runs}", f"report.out_dir={out}", cwd=tmp_path)
    assert res.returncode == 2 and "already holds an assets/ folder that no simeval report wrote" in res.stderr
    assert (out / "assets" / "logo.png").read_bytes() == b"mine"
    # a report's own folder is rebuilt in place, a figure gone since the last build no longer linked
    from PIL import Image

    (out / "assets" / "logo.png").unlink()
    (out / "assets").rmdir()
    figs = tmp_path / "figs"
    figs.mkdir()
    for name in ("a.png", "b.png"):
        Image.new("RGB", (8, 8)).save(figs / name)
    for gone in (None, "b.png"):
        if gone:
            (figs / gone).unlink()
        res = _run("report.py", "report=html", f"report.runs_dir={runs}", f"report.out_dir={out}",
                   f"report.figures_dir={figs}", cwd=tmp_path)
        assert res.returncode == 0, res.stderr[-2000:]
    assert sorted(p.name for p in (out / "assets").rglob("*.png")) == ["a.png"]
    assert "No result.json here." in (out / "index.html").read_text()


def test_an_agreement_run_is_summarised_by_its_pooled_r_over_mae():
    from simeval.report.html import headline_values

    rows = [{"table": "scene_alignment", "pipeline": "RoboGen", "judge": "GPT-4v", "r_over_mae": 0.2},
            {"table": "scene_alignment", "pipeline": "all", "judge": "GPT-4v", "r_over_mae": 0.87},
            {"table": "task_completion", "pipeline": "all", "judge": "LLava-1.5", "r_over_mae": None}]
    assert headline_values({"metric": "agreement", "values": rows}) == [
        ("scene_alignment GPT-4v (all) r/MAE", 0.87), ("task_completion LLava-1.5 (all) r/MAE", None)]


def test_a_runs_table_cell_cut_at_six_values_says_so_and_links_the_whole_record(tmp_path):
    from simeval.report.html import build_html_report
    from simeval.results import write_result

    write_result(tmp_path / "runs" / "many", metric="collect", version="1",
                 values={f"task{i}": {"episodes": i} for i in range(9)})
    write_result(tmp_path / "runs" / "few", metric="collect", version="1", values={"task0": {"episodes": 3}})
    page = build_html_report(tmp_path / "runs", tmp_path / "site").read_text()
    rows = [row.split("</tr>")[0] for row in page.split("<tr>")]
    many = next(row for row in rows if ">many</a>" in row)
    few = next(row for row in rows if ">few</a>" in row)
    assert many.count(".episodes: ") == 6 and "task5.episodes: 5" in many and "task6" not in many
    link = re.search(r"<a href='([^']+)'>many</a>", many).group(1)
    assert f"<a href='{link}'>… all values</a>" in many and (tmp_path / "site" / link).is_file()
    assert "all values" not in few


def test_two_reports_into_one_folder_take_turns(tmp_path, monkeypatch):
    """Each report deletes the previous assets/ before writing its own; two at once would delete each other's files
    mid-write. The build holds an exclusive lock on <out>/.report.lock: while another holder has it, the lock cannot
    be taken (checked without waiting), and every build takes it."""
    import fcntl

    from simeval.report import html as report_html

    runs = tmp_path / "runs"
    runs.mkdir()
    taken = []
    real = report_html._exclusive

    def recording(path):
        taken.append(path)
        return real(path)

    monkeypatch.setattr(report_html, "_exclusive", recording)
    page = report_html.build_html_report(runs)
    assert taken == [runs / "report" / ".report.lock"] and page.is_file()
    with real(taken[0]), open(taken[0], "w") as other:
        with pytest.raises(BlockingIOError):
            fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
    with open(taken[0], "w") as other:  # released when the holder is done
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)


def test_the_papers_tables_and_figures_lead(tmp_path):
    from simeval.report.html import build_html_report

    runs, tables, figures = tmp_path / "runs", tmp_path / "tables", tmp_path / "figures"
    for d in (runs, tables, figures):
        d.mkdir()
    for name in ("control_dose", "oracle_success_bbsea", "table5", "table3"):
        (tables / f"{name}.md").write_text("| a | b |\n|---|---|\n| 1 | 2 |\n")
    png = (ROOT / "outputs" / "figures").glob("*.png")
    first = next(png)
    for name in ("contact_sheet_bbsea", "figure3", "control_dose"):
        shutil.copy(first, figures / f"{name}.png")
    page = build_html_report(runs, tmp_path / "out", tables_dir=tables, figures_dir=figures).read_text()
    assert re.findall(r"<h3 id='table-([^']+)'>", page) == ["table3.md", "table5.md", "control_dose.md",
                                                            "oracle_success_bbsea.md"]
    assert [m for m in re.findall(r"<figcaption>([^<·]+)", page)] == ["figure3.png", "contact_sheet_bbsea.png",
                                                                      "control_dose.png"]
    assert "not computed from the runs above" in page


def test_a_runs_videos_play_in_the_report(tmp_path):
    """A world-model run's open-loop videos (videos/*.mp4) and a policy run's rollout videos (*.mp4) are copied into
    the report and embedded; a run without videos adds nothing."""
    from simeval.media import write_video
    from simeval.report.html import build_html_report

    runs = tmp_path / "runs"
    frames = np.zeros((4, 16, 16, 3), np.uint8)
    for run, video in (("wm", "videos/open_loop_stack.mp4"), ("policy", "best_train.mp4"), ("plain", None)):
        (runs / run).mkdir(parents=True)
        (runs / run / "result.json").write_text(json.dumps({"metric": "m", "identity": {}, "values": {}}))
        if video:
            write_video(frames, runs / run / video, fps=4)
    out = tmp_path / "out"
    page = build_html_report(runs, out).read_text()
    srcs = re.findall(r"<video controls muted preload='metadata' src='([^']+)'>", page)
    assert sorted(Path(s).name for s in srcs) == ["best_train.mp4", "open_loop_stack.mp4"]
    assert all((out / s).stat().st_size > 0 for s in srcs)
    assert "<figcaption>open_loop_stack</figcaption>" in page
