"""`make report` (src/report.py report=all) and the report door (src/report.py) rebuild tables and figures from real
result.json files only (conftest: world_model_runs, policy_run); missing inputs are one line each, not a traceback."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}


def py(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=300)


def report_all(*overrides: str, cwd: Path) -> subprocess.CompletedProcess:
    return py(str(ROOT / "src" / "report.py"), "report=all", *overrides, cwd=cwd)


@pytest.fixture
def outputs(world_model_runs, policy_run, tmp_path) -> Path:
    """An outputs/ folder as `make table4 table5` leave it: runs under outputs/multiruns and outputs/runs."""
    out = tmp_path / "outputs"
    shutil.copytree(world_model_runs / "table4", out / "multiruns" / "diversity" / "sweep")
    shutil.copytree(policy_run, out / "runs" / "generalization" / "run")
    return out


def test_report_rebuilds_tables_4_and_5_with_figures_and_notes_what_has_no_runs(outputs, tmp_path):
    r = report_all(cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == ("Table 3: skipped: no text_diversity result.json under outputs/table3/runs "
                        "(`make table3` runs the sweep)")
    assert lines[1] == ("Table 4: note: runs trained on 1, 2, 3 episodes per task are not in the table "
                        "(report.table4.episodes 10,20,40 chose its columns)")
    assert lines[3] == ("Table 4 (held-out): skipped: no protocol=heldout dynamics_diversity result.json under "
                        "outputs (`make table4-heldout`, or src/diversity.py: its default protocol)")  # fixture: paper
    assert lines[5].startswith("Figure 4: skipped: no quality result.json under outputs/runs/quality")
    assert len(lines) == 7 and "Traceback" not in r.stderr
    tables, figures = outputs / "tables", outputs / "figures"
    for stem in ("table4", "table5"):
        assert all((tables / f"{stem}.{ext}").stat().st_size > 0 for ext in ("csv", "md", "tex"))
        assert (figures / f"{stem}.png").read_bytes()[:4] == b"\x89PNG"
        assert (figures / f"{stem}.pdf").read_bytes()[:5] == b"%PDF-"
    # Table 4: ours beside the paper's, in Markdown and booktabs LaTeX (underscores escaped)
    runs = [json.loads(p.read_text()) for p in (outputs / "multiruns").rglob("result.json")]
    diverse = {rec["identity"]["episodes"]: rec["values"]["eval"]["image_error"] for rec in runs
               if rec["identity"]["task_group"] == "diverse"}
    tex = (tables / "table4.tex").read_text()
    assert "\\toprule" in tex and "\\bottomrule" in tex and "table\\_top" in tex and "table_top" not in tex
    assert " & stacking & -- & 115.0 / -- & 67.2 / -- & 24.5 / -- & " in tex  # not run here: the paper's only
    assert "diverse" not in (tables / "table4.md").read_text()  # no run at 10/20/40 episodes: the paper's rows only
    # with our episode counts in the paper's columns, each cell is the run's own number
    r = report_all("report.steps=[table4]", "report.table4.episodes=[1,2,3]", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    md = (tables / "table4.md").read_text()
    assert (f"| gensim | diverse | tiny | — / {diverse[1]:.1f} | — / {diverse[2]:.1f} | — / {diverse[3]:.1f} |"
            in md)
    assert "- Ours trained on 1/2/3 episodes per task in the columns of the paper's 10/20/40" in md
    # Table 5: the run's successes with their Wilson interval beside the paper's 0.15 (GenSim stacking)
    gen = json.loads(next((outputs / "runs").rglob("result.json")).read_text())
    s = gen["values"]["splits"]["eval"]["success"]
    tex = (tables / "table5.tex").read_text()
    line = next(x for x in tex.splitlines() if x.startswith("gensim & stacking & 0.15 & "))
    assert f"{s['rate']:.2f} [{s['ci'][0]:.2f}, {s['ci'][1]:.2f}] ({s['k']}/{s['n']})" in line
    # the preset, then the demonstrations it trained on (every stored episode), then the runs
    assert line.endswith("& tiny & all & 1 \\\\") and "robogen & table\\_top & 0.00 & - & - & - & - & - & - & 0 \\\\" in tex


def test_missing_or_broken_inputs_are_one_line_each(tmp_path):
    r = report_all(cwd=tmp_path)  # no outputs/ at all
    assert r.returncode == 0 and r.stderr == ""
    assert [x.split(":")[0] for x in r.stdout.splitlines()] == ["Table 3", "Table 4", "Table 4 (held-out)",
                                                                 "Table 5", "Figure 4", "HTML report"]
    assert all(": skipped: " in x for x in r.stdout.splitlines())
    assert not (tmp_path / "outputs").exists()  # nothing written from nothing
    for kind in ("table4", "table5"):
        r = py(str(ROOT / "src" / "report.py"), f"report={kind}", "report.runs_dir=outputs", cwd=tmp_path)
        assert r.returncode == 2 and r.stderr.count("\n") == 1
        assert r.stderr.startswith("error: report.runs_dir=outputs: no such folder; give the folder that holds the "
                                   "runs' result.json files (`make table")  # the key, and what makes the runs
    for kind in ("table4", "table4_heldout", "table5", "table3", "figure4"):  # the same lines as report=all's
        r = py(str(ROOT / "src" / "report.py"), f"report={kind}", f"report.runs_dir={ROOT / 'README.md'}", cwd=tmp_path)
        assert r.returncode == 2 and r.stderr == f"error: report.runs_dir={ROOT / 'README.md'}: is a file, not a " \
            "folder of runs; give the folder that holds the runs' result.json files\n", (kind, r.stderr)
    (tmp_path / "outputs").mkdir()
    r = py(str(ROOT / "src" / "report.py"), "report=table5", "report.runs_dir=outputs", cwd=tmp_path)
    assert r.returncode == 2 and "no generalization result.json under outputs: run the" in r.stderr
    (tmp_path / "outputs").rmdir()
    bad = tmp_path / "outputs" / "runs" / "x" / "result.json"
    bad.parent.mkdir(parents=True)
    bad.write_text("{not json")
    r = report_all("report.steps=[table4,table5]", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stdout.splitlines()[0] == (f"Table 4: not written: cannot read {Path('outputs/runs/x/result.json')}: "
                                        "Expecting property name enclosed in double quotes: line 1 column 2 (char 1)")
    assert r.stderr == ("error: report=all: 2 of its steps not written (Table 4, Table 5); each step's line above "
                        "says why\n")
    r = report_all("report.steps=[table6]", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == ("error: report.steps=['table6']: unknown step 'table6'; give some of "
                                              "table3, table4, table4_heldout, table5, figure4, html\n")
    for steps, why in (("[]", "empty"), ("[table4,table4]", "table4 twice")):
        r = report_all(f"report.steps={steps}", cwd=tmp_path)
        assert r.returncode == 2 and r.stderr.startswith("error: report.steps=") and f": {why}; give some" in r.stderr
    r = report_all("report.steps=table4", cwd=tmp_path)  # one step, not a list: that step
    assert r.returncode == 2 and r.stdout.startswith("Table 4: not written: cannot read ")
    assert r.stderr.startswith("error: report=all: 1 of its steps not written (Table 4)") and r.stderr.count("\n") == 1
    # a runs folder the user named that is not there (or is a file) is an error, not "nothing run yet"
    (tmp_path / "README.md").write_text("x")
    r = report_all("report.steps=[table4,html]", "report.table4.runs_dir=/nonexistent",
                   "report.html.runs_dir=README.md", cwd=tmp_path)
    assert r.returncode == 2 and r.stdout.splitlines() == [
        ("Table 4: not written: report.table4.runs_dir=/nonexistent: no such folder; give the folder that holds the "
         "runs' result.json files (`make table4` trains the world models)"),
        ("HTML report: not written: report.html.runs_dir=README.md: is a file, not a folder of runs; give the folder "
         "that holds the runs' result.json files")]
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: report=all: 2 of its steps not written")


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_report_is_listed_and_runs_the_rebuild(outputs, tmp_path):
    """The Makefile's own `report` target, with the checkout's Python (its setup stamp stands in for make setup)."""
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    for f in ("requirements.txt", "requirements-dev.txt", "requirements-models.txt", "pyproject.toml"):
        (tmp_path / f).write_text("")
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").write_text("")
    for folder in ("src", "conf"):
        (tmp_path / folder).symlink_to(ROOT / folder)
    help_ = subprocess.run(["make", "--no-print-directory", "help"], cwd=tmp_path, capture_output=True, text=True)
    assert "rebuild Tables 3-5 (Table 4 under both protocols), their figures, Figure 4 and the HTML report" in help_.stdout
    r = subprocess.run(["make", "--no-print-directory", "report", f"PY={sys.executable}"], cwd=tmp_path, env=ENV,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Table 4: outputs/tables/table4.csv" in r.stdout and "figures/table5.png" in r.stdout
    assert (tmp_path / "outputs" / "runs" / "report" / "index.html").is_file()


def test_table4_says_in_the_file_which_runs_it_leaves_out():
    from simeval.measures.dynamics_diversity import table4

    _, body, notes = table4.display(table4.build([], episodes=(10, 20, 40)), (10, 20, 40), unused=[1, 2, 4])
    assert body and all("—" in cell for row in body for cell in row[3:6])  # no run at 10/20/40: paper / —
    assert ("Runs trained on 1/2/4 episodes per task exist but are not in this table (its columns are 10/20/40): "
            "build one for them with report.episodes=[1,2,4]") in notes  # the override the report door parses


def test_table4_suggests_three_counts_even_when_fewer_runs_are_left_out():
    """A table has one count per paper column: runs at 2 and 3 episodes are suggested with one of the shown counts
    (the builder refuses two), and five are cut to the three smallest."""
    from simeval.measures.dynamics_diversity import table4

    _, _, notes = table4.display(table4.build([], episodes=(10, 20, 40)), (10, 20, 40), unused=[3, 2])
    assert notes[-1].endswith("build one for them with report.episodes=[2,3,10]")
    _, _, notes = table4.display(table4.build([], episodes=(1, 2, 4)), (1, 2, 4), unused=[40, 5, 80, 10, 20])
    assert notes[-1].endswith("report.episodes=[5,10,20]")


def _commit_all(repo: Path) -> None:
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
    subprocess.run([*git, "add", "-A", "outputs/tables", "outputs/figures"], cwd=repo, check=True)
    subprocess.run([*git, "commit", "-qm", "committed results"], cwd=repo, check=True)


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_reports_never_replace_committed_results_unless_asked(outputs, tmp_path):
    """A checkout's committed Tables 4/5 stay as committed when a user rebuilds reports from their own runs: each
    command refuses in one line naming the file and the flag, changes nothing, and replaces them with the flag."""
    r = report_all("report.steps=[table4,table5]", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (outputs / "tables" / "table5.md").write_text("committed Table 5\n")
    _commit_all(tmp_path)
    before = {p: p.read_bytes() for p in (outputs / "tables").iterdir()}
    r = report_all("report.steps=[table4,table5]", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stdout.splitlines() == [  # one line per step not written, each naming the keys that write elsewhere
        f"Table 4: not written: {Path('outputs/tables/table4.csv')} is a committed result and would be replaced by a "
        "table of the runs on disk; write elsewhere (report.table4.out= and report.table4.figure=) or replace it with "
        "overwrite=true (make: OVERWRITE=1)",
        f"Table 5: not written: {Path('outputs/tables/table5.csv')} is a committed result and would be replaced by a "
        "table of the runs on disk; write elsewhere (report.table5.out= and report.table5.figure=) or replace it with "
        "overwrite=true (make: OVERWRITE=1)"]
    assert r.stderr == ("error: report=all: 2 of its steps not written (Table 4, Table 5); each step's line above "
                        "says why\n")  # the one error line
    for value in ("maybe", "yess"):  # anything but true/false (or yes/no, on/off, 1/0) is refused before a write
        r = report_all("report.steps=[table4,table5]", f"overwrite={value}", cwd=tmp_path)
        assert r.returncode == 2 and r.stderr == f"error: overwrite='{value}': expected true or false\n", r.stderr
    for kind in ("table4", "table5"):  # the report door (what `make report-table4` / `report-table5` run)
        r = py(str(ROOT / "src" / "report.py"), f"report={kind}", cwd=tmp_path)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "is a committed result" in r.stderr, r.stderr
        assert r.stderr.rstrip().endswith("replace it with overwrite=true (make: OVERWRITE=1)")
    assert {p: p.read_bytes() for p in (outputs / "tables").iterdir()} == before
    r = py(str(ROOT / "src" / "report.py"), "report=table5", "overwrite=true", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (outputs / "tables" / "table5.md").read_text() != "committed Table 5\n"
    r = report_all("report.steps=[table4]", "overwrite=true", cwd=tmp_path)
    assert r.returncode == 0, r.stderr


def test_the_report_door_builds_tables_4_and_5_as_the_library_does(outputs, tmp_path):
    """src/report.py report=table4|table5 (the one report entrypoint) is the library function it calls
    (simeval.report.rebuild), called without Hydra: the same runs give the same bytes."""
    from simeval.report.rebuild import rebuild_table4, rebuild_table5

    for kind in ("table4", "table5"):
        a = (tmp_path / "outputs", tmp_path / "a" / kind, tmp_path / "a" / f"{kind}.png")
        rebuild_table4(*a, episodes=(1, 2, 3)) if kind == "table4" else rebuild_table5(*a)
        extra = ["report.episodes=[1,2,3]"] if kind == "table4" else []
        r = py(str(ROOT / "src" / "report.py"), f"report={kind}", "report.runs_dir=outputs", f"report.out=b/{kind}",
               f"report.figure=b/{kind}.png", *extra, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        a = sorted(p.name for p in (tmp_path / "a").iterdir())
        assert a == sorted(p.name for p in (tmp_path / "b").iterdir()) and f"{kind}.md" in a
        for name in a:
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    r = py(str(ROOT / "src" / "report.py"), "report=table4_heldout", "report.runs_dir=outputs", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.startswith("error: no protocol=heldout dynamics_diversity result.json")
    # a committed table is refused naming the door's own key, not another command's flag
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path / "b", check=True)
    subprocess.run([*git, "add", "table5.md"], cwd=tmp_path / "b", check=True)
    subprocess.run([*git, "commit", "-qm", "committed"], cwd=tmp_path / "b", check=True)
    r = py(str(ROOT / "src" / "report.py"), "report=table5", "report.runs_dir=outputs", "report.out=b/table5",
           "report.figure=b/table5.png", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.rstrip().endswith("replace it with overwrite=true (make: OVERWRITE=1)"), r.stderr


@pytest.mark.parametrize("kind,files", [
    ("table4_heldout", ["table4_heldout.csv", "table4_heldout.md"]),
    ("table5", [f"table5{part}.{x}" for part in ("", "_detail") for x in ("csv", "md", "tex")])])
def test_a_committed_table_is_drawn_again_from_its_csv_alone_with_runs_dir_null(kind, files, tmp_path):
    """`report.runs_dir=null` says on purpose that there are no runs (a fresh clone, a change to the plotting
    code): the tables come back byte for byte from the kept CSV (and Table 5's detail beside it), and the figure
    is drawn from them."""
    r = py(str(ROOT / "src" / "report.py"), f"report={kind}", "report.runs_dir=null",
           f"report.keep=[{ROOT / 'outputs' / 'tables' / f'{kind}.csv'}]", f"report.out={tmp_path / kind}",
           f"report.figure={tmp_path / kind}.png", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for name in files:
        assert (tmp_path / name).read_bytes() == (ROOT / "outputs" / "tables" / name).read_bytes(), name
    assert (tmp_path / f"{kind}.png").read_bytes().startswith(b"\x89PNG")
    if shutil.which("git") is None:
        return
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run([*git, "add", files[0]], cwd=tmp_path, check=True)
    subprocess.run([*git, "commit", "-qm", "committed"], cwd=tmp_path, check=True)
    r = py(str(ROOT / "src" / "report.py"), f"report={kind}", "report.runs_dir=null",
           f"report.keep=[{ROOT / 'outputs' / 'tables' / f'{kind}.csv'}]", f"report.out={tmp_path / kind}",
           f"report.figure={tmp_path / kind}.png", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == (  # names what would replace it: no runs are involved
        f"error: {tmp_path / files[0]} is a committed result and would be replaced by a table of the kept tables "
        "alone; write elsewhere (report.out= and report.figure=) or replace it with overwrite=true (make: "
        "OVERWRITE=1)\n"), r.stderr


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_report_that_would_drop_committed_rows_names_the_keep_that_keeps_them(tmp_path):
    """A report of one sweep's runs, over a committed table of many groups, would write a table of that row alone:
    the refusal says how many rows would go and which key keeps them; asked to, it replaces them and says so."""
    from simeval.measures.dynamics_diversity import table4_heldout
    from simeval.writing.tables import rows_lost

    committed_csv = ROOT / "outputs" / "tables" / "table4_heldout.csv"
    rows = table4_heldout.read_rows(committed_csv)
    shutil.copy(committed_csv, tmp_path / "table4_heldout.csv")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run([*git, "add", "table4_heldout.csv"], cwd=tmp_path, check=True)
    subprocess.run([*git, "commit", "-qm", "committed"], cwd=tmp_path, check=True)
    one = tmp_path / "one" / "table4_heldout"
    one.parent.mkdir()
    table4_heldout.write(rows[:1], one)  # another sweep's table: one group
    args = [str(ROOT / "src" / "report.py"), "report=table4_heldout", "report.runs_dir=null",
            f"report.keep=[{one}.csv]", f"report.out={tmp_path / 'table4_heldout'}",
            f"report.figure={tmp_path / 'one' / 'figure.png'}"]
    r = py(*args, cwd=tmp_path)
    others = [f"{row['pipeline']}/{row['group']}" for row in rows[1:4]]
    assert r.returncode == 2 and r.stderr == (
        f"error: {tmp_path / 'table4_heldout.csv'} is a committed result and would be replaced by a table of the "
        f"kept tables alone; {len(rows) - 1} of its {len(rows)} rows would go (groups without runs here: "
        f"{', '.join(others)} and {len(rows) - 4} more); report.keep=[{tmp_path / 'table4_heldout.csv'}] keeps "
        f"them (make: KEEP={tmp_path / 'table4_heldout.csv'}); write elsewhere (report.out= and report.figure=) or replace it with overwrite=true (make: "
        "OVERWRITE=1)\n"), r.stderr
    r = py(*args[:3], f"report.keep=[{one}.csv,{tmp_path / 'table4_heldout.csv'}]", *args[4:], cwd=tmp_path)
    assert r.returncode == 2 and "rows would go" not in r.stderr  # kept: none would go (still committed)
    r = py(*args, "overwrite=true", cwd=tmp_path)
    assert r.returncode == 0 and f"replaced as asked: {len(rows) - 1} of its {len(rows)} rows went" in r.stdout
    assert len(table4_heldout.read_rows(tmp_path / "table4_heldout.csv")) == 1

    def key(row):
        return tuple(str(row.get(c)) for c in table4_heldout.ROW_KEY)

    assert rows_lost(committed_csv, [], rows, table4_heldout.read_rows, key) == ""  # every row still there
    assert rows_lost(one.with_suffix(".csv"), [], [], table4_heldout.read_rows, key) == ""  # not committed


def test_runs_dir_null_without_a_kept_table_or_for_another_report_is_one_line(tmp_path):
    r = py(str(ROOT / "src" / "report.py"), "report=table5", "report.runs_dir=null", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == (
        "error: report.runs_dir=null draws from report.keep's tables alone, and it is empty; give "
        "report.keep=[outputs/tables/table5.csv] (or a folder of runs)\n")
    r = py(str(ROOT / "src" / "report.py"), "report=table4", "report.runs_dir=null",
           f"report.keep=[{ROOT / 'outputs' / 'tables' / 'table4.csv'}]", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == (
        "error: report.runs_dir=null: only report=table4_heldout and report=table5 can be drawn from their kept "
        "tables alone; give report.runs_dir=<the folder that holds the runs>\n")
    alone = tmp_path / "mine" / "table5.csv"  # a copy without table5_detail.csv beside it: refused, not empty detail
    alone.parent.mkdir()
    shutil.copy(ROOT / "outputs" / "tables" / "table5.csv", alone)
    r = py(str(ROOT / "src" / "report.py"), "report=table5", "report.runs_dir=null", f"report.keep=[{alone}]",
           f"report.out={tmp_path / 't5'}", f"report.figure={tmp_path / 't5.png'}", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == (
        f"error: report.keep: {alone} has no table5_detail.csv beside it, from which the per-task table is drawn "
        "when there are no runs; keep the two files together\n")
    assert not (tmp_path / "outputs").exists() and not list(tmp_path.glob("t5*"))
    (tmp_path / "outputs").mkdir()  # keep beside an empty runs folder: the error points at runs_dir=null
    r = py(str(ROOT / "src" / "report.py"), "report=table5", "report.runs_dir=outputs", f"report.keep=[{alone}]",
           cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.endswith("(report.runs_dir=null draws from the kept tables alone)\n")
