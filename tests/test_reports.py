"""Reports merge runs by their identity: unique run folders, repeated seeds averaged, conflicting records refused,
partial re-runs keep the other groups, Figure 4 counts distinct tasks."""

import csv
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

from simeval.errors import UserError
from simeval.measures.text_diversity.artefacts import build_text_diversity_report
from simeval.measures.quality.figure4 import build_quality_figure, quality_points
from simeval.measures.text_diversity.metric import STATISTICS
from simeval.measures.text_diversity.table3 import tidy_rows
from simeval.results import read_results, register_run_suffix_resolver, write_result

ROOT = Path(__file__).resolve().parents[1]
SPEC = yaml.safe_load((ROOT / "conf" / "report" / "table3.yaml").read_text())
SETTINGS = {"n_boot": 1000, "subsample_n": "auto", "subsample_repeats": 50}


def _group(div, n=5):
    return {"n": n, **{s: div for s in STATISTICS},
            "div_ci": [div - 0.1, div + 0.1], "subsample": {"n": 3, "div_mean": div}}


def td_record(root, name, *, values, pipeline="gensim", embedding="minilm", seed=0, task_group="each",
              model="sentence-transformers/all-MiniLM-L6-v2", settings=SETTINGS, created=None, sha="abc"):
    path = write_result(Path(root) / name, metric="text_diversity", version="2.0", values=values, seed=seed,
                        pipeline=pipeline, embedding=embedding,
                        identity=dict(pipeline=pipeline, source="auto", tasks_sha="t1", task_group=task_group,
                                      embedding=embedding, model=model, settings=settings))
    rec = json.loads(path.read_text())
    rec["created"] = created or rec["created"]
    rec["git_sha"] = sha
    path.write_text(json.dumps(rec))
    return path


EACH = {"stacking": _group(0.4), "placement": _group(0.5), "all": _group(0.7, n=10)}


def _table(out):
    return {(r["Method"], r["Task Group"]): r for r in csv.DictReader((out / "table3.csv").open())}


def _build(runs, out):
    return build_text_diversity_report(runs, out, id="table3", rows=SPEC["rows"], columns=SPEC["columns"],
                                       caption=SPEC["caption"])


# --- identity in result.json and unique run folders ----------------------------------------------------------

def test_write_result_records_an_identity(tmp_path):
    path = write_result(tmp_path, metric="m", version="1.0", values={}, seed=3, identity={"pipeline": "gensim",
                                                                                           "seed": 99})
    assert json.loads(path.read_text())["identity"] == {"metric": "m", "version": "1.0", "pipeline": "gensim",
                                                        "seed": 3}


@pytest.mark.parametrize("conf,key", [("hydra/default.yaml", "hydra.run.dir"),
                                      ("hydra/default.yaml", "hydra.sweep.dir"),
                                      ("experiment/table3.yaml", "hydra.sweep.dir")])
def test_run_folders_started_in_the_same_second_differ(conf, key):
    """Two runs whose clocks read the same second (here: the same microsecond) still get two folders."""
    from hydra.core.utils import setup_globals

    register_run_suffix_resolver()
    node = yaml.safe_load((ROOT / "conf" / conf).read_text())
    node = node if conf.startswith("experiment") else {"hydra": node}
    node["paths"] = yaml.safe_load((ROOT / "conf" / "paths" / "default.yaml").read_text())  # what the dirs name
    try:
        OmegaConf.register_new_resolver("now", lambda pattern: "2026-01-01_00-00-00-000000", replace=True)
        dirs = {OmegaConf.select(OmegaConf.merge(node, {"hydra": {"job": {"name": "x", "num": 0}}}), key)
                for _ in range(2)}
    finally:
        setup_globals()  # Hydra's own ${now:}
    assert len(dirs) == 2, dirs


def test_two_runs_started_together_keep_both_results(tmp_path):
    """The whole path: two processes launched at once, default run folders, two result.json files."""
    env = {**os.environ, "BBSEA_ROOT": "", "BBSEA_TASKS": "", "PYTHONPATH": str(ROOT / "src")}
    args = [sys.executable, str(ROOT / "src" / "text_diversity.py"), "pipeline=bbsea", "on_missing_source=record"]
    procs = [subprocess.Popen(args, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for _ in range(2)]
    for p in procs:
        assert p.wait(timeout=300) == 0, p.stderr.read().decode()[-2000:]
    results = list((tmp_path / "outputs" / "runs").rglob("result.json"))
    assert len(results) == 2
    assert json.loads(results[0].read_text())["identity"]["pipeline"] == "bbsea"


# --- Table 3 merging ------------------------------------------------------------------------------------------

def test_repeated_seeds_are_averaged_with_their_spread(tmp_path):
    td_record(tmp_path / "runs", "a", values=EACH, seed=0)
    td_record(tmp_path / "runs", "b", values={**EACH, "stacking": _group(0.6)}, seed=1)
    _build(tmp_path / "runs", tmp_path / "out")
    row = _table(tmp_path / "out")[("GenSim", "Stacking")]
    assert row["MiniLM-L6-v2"] == "0.50 ± 0.14"
    assert _table(tmp_path / "out")[("GenSim", "Placement")]["MiniLM-L6-v2"] == "0.50 ± 0.00"
    assert "x ± s: mean and standard deviation over repeated seeds" in (tmp_path / "out" / "table3.md").read_text()
    tidy = [r for r in csv.DictReader((tmp_path / "out" / "table3_tidy.csv").open())
            if r["group"] == "stacking" and r["statistic"] == "div"]
    assert [(r["n_seeds"], r["seeds"], float(r["value"])) for r in tidy] == [("2", "0;1", 0.5)]


def test_a_rerun_of_the_same_seed_replaces_the_older_one(tmp_path):
    td_record(tmp_path / "runs", "a", values=EACH, created="2026-01-01T00:00:00+00:00")
    td_record(tmp_path / "runs", "b", values={**EACH, "stacking": _group(0.45)}, created="2026-01-02T00:00:00+00:00")
    rows = [r for r in tidy_rows(read_results(tmp_path / "runs")) if r["group"] == "stacking"
            and r["statistic"] == "div"]
    assert [(r["value"], r["n_seeds"]) for r in rows] == [(0.45, 1)]


def test_two_records_claiming_one_cell_with_different_settings_are_refused(tmp_path):
    a = td_record(tmp_path / "runs", "a", values=EACH, embedding="hf", model="/models/one")
    b = td_record(tmp_path / "runs", "b", values=EACH, embedding="hf", model="/models/two", seed=1)
    with pytest.raises(UserError) as e:
        _build(tmp_path / "runs", tmp_path / "out")
    msg = str(e.value)
    assert str(a) in msg and str(b) in msg and "model ('/models/one' vs '/models/two')" in msg
    assert "embedding.name=" in msg and "\n" not in msg
    # the entrypoint: one line on stderr, exit 2
    res = subprocess.run([sys.executable, str(ROOT / "src" / "report.py"), f"report.runs_dir={tmp_path / 'runs'}",
                          f"report.out_dir={tmp_path / 'out'}"], cwd=ROOT, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src")}, timeout=300)
    assert res.returncode == 2 and res.stderr.strip() == f"error: {msg}"


def test_different_metric_settings_are_refused_too(tmp_path):
    td_record(tmp_path / "runs", "a", values=EACH)
    td_record(tmp_path / "runs", "b", values={"stacking": _group(0.4)}, task_group="stacking",
              settings={**SETTINGS, "n_boot": 20})
    with pytest.raises(UserError, match=r"settings.n_boot \(1000 vs 20\)"):
        _build(tmp_path / "runs", tmp_path / "out")


def test_a_partial_rerun_keeps_the_other_groups_and_says_where_rows_come_from(tmp_path):
    td_record(tmp_path / "runs", "a_each", values=EACH, created="2026-01-01T00:00:00+00:00")
    td_record(tmp_path / "runs", "b_stacking", values={"stacking": _group(0.42)}, task_group="stacking",
              created="2026-01-02T00:00:00+00:00")
    _build(tmp_path / "runs", tmp_path / "out")
    table = _table(tmp_path / "out")
    assert table[("GenSim", "Stacking")]["MiniLM-L6-v2"] == "0.42"  # the newer run of that group
    assert table[("GenSim", "Placement")]["MiniLM-L6-v2"] == "0.50"  # kept from the complete run
    assert table[("GenSim", "All")]["MiniLM-L6-v2"] == "0.70"
    md = (tmp_path / "out" / "table3.md").read_text()
    assert ("GenSim [MiniLM-L6-v2] rows come from different runs: Stacking from task_group=stacking, seed 0; "
            "Placement, All from task_group=each, seed 0") in md
    sources = list(csv.DictReader((tmp_path / "out" / "table3_sources.csv").open()))
    assert {(r["group"], Path(r["path"]).parent.name) for r in sources} == {
        ("stacking", "b_stacking"), ("placement", "a_each"), ("all", "a_each")}


def test_missing_is_noted_only_without_values(tmp_path):
    write_result(tmp_path / "runs" / "m", metric="text_diversity", version="2.0", values={}, status="missing",
                 pipeline="gensim", embedding="minilm", missing_hint="set pipeline.grouped_file=...")
    td_record(tmp_path / "runs", "a", values=EACH)
    _build(tmp_path / "runs", tmp_path / "out")
    assert "GenSim [MiniLM-L6-v2] missing" not in (tmp_path / "out" / "table3.md").read_text()


# --- Figure 4 -------------------------------------------------------------------------------------------------

def q_record(root, name, *, tasks=("a", "b", "c"), label=None, model="gpt-4o", score=3.0):
    values = {"scene_alignment": {t: {"mean": score, "var": 0.1} for t in tasks},
              "task_completion": {t: {"mean": 2 * score, "var": 0.2} for t in tasks}}
    return write_result(Path(root) / name, metric="quality", version="1.0", values=values, judge="model",
                        label=label, tasks={t: {"pipeline": "gensim"} for t in tasks},
                        config={"judge": {"kind": "model", "provider": {"model": model}},
                                "scene_alignment_mode": "vlm", "captioner": {"kind": "none"}})


def test_figure4_counts_a_rerun_of_the_same_bundles_once(tmp_path):
    for i in range(7):
        q_record(tmp_path / "runs", f"r{i}", score=3.0 + (i % 2))
    [point] = quality_points(read_results(tmp_path / "runs"))
    assert point["n_tasks"] == 3 and point["scene_alignment"] == pytest.approx(3 + 3 / 7)
    written = build_quality_figure(tmp_path / "runs", tmp_path / "out")
    row = next(csv.DictReader(written["table"][0].open()))
    assert row["Tasks"] == "3"


def test_figure4_refuses_two_judges_in_one_point(tmp_path):
    a = q_record(tmp_path / "runs", "a", model="gpt-4o")
    b = q_record(tmp_path / "runs", "b", model="llava")
    with pytest.raises(UserError) as e:
        quality_points(read_results(tmp_path / "runs"))
    assert str(a) in str(e.value) and str(b) in str(e.value) and "judge_model ('gpt-4o' vs 'llava')" in str(e.value)
    q_record(tmp_path / "runs2", "a", model="gpt-4o", label="GenSim-gpt")
    q_record(tmp_path / "runs2", "b", model="llava", label="GenSim-llava")
    assert len(quality_points(read_results(tmp_path / "runs2"))) == 2


def test_a_sweep_that_found_no_task_descriptions_does_not_overwrite_the_table(tmp_path):
    """A fresh clone without the authors' task files: every run is `missing`; the committed table stays."""
    for p in ("gensim", "robogen"):
        write_result(tmp_path / "runs" / p, metric="text_diversity", version="2.0", values={}, status="missing",
                     pipeline=p, embedding="minilm", missing_hint=f"set the {p} task source")
    out = tmp_path / "out"
    out.mkdir()
    (out / "table3.md").write_text("| committed numbers |\n")
    with pytest.raises(UserError, match="found any task descriptions, so nothing was written"):
        _build(tmp_path / "runs", out)
    assert (out / "table3.md").read_text() == "| committed numbers |\n"
    assert sorted(p.name for p in out.iterdir()) == ["table3.md"]


def test_the_heldout_figure_draws_every_row_past_ten_in_its_own_colour(monkeypatch, tmp_path):
    """The figure's colour list once held ten colours and zip() stopped there: the committed figure dropped
    metaworld and both robogen rows without a word."""
    from matplotlib.colors import to_rgba

    from simeval.writing import figures
    from simeval.measures.dynamics_diversity import table4_heldout

    rows = table4_heldout.read_rows(ROOT / "outputs" / "tables" / "table4_heldout.csv")
    assert len(rows) > 10
    drawn, markers, keys = {}, {}, []

    def keep(fig, path, **kwargs):  # the figure as saved: its full-frame panel has one legend entry per row
        ax = fig.axes[2]
        handles, labels = ax.get_legend_handles_labels()
        drawn.update(zip(labels, (to_rgba(h.lines[0].get_color()) for h in handles)))
        markers.update(zip(labels, (h.lines[0].get_marker() for h in handles)))
        keys.extend(t.get_text() for t in fig.legends[0].get_texts())
        return path

    monkeypatch.setattr(figures, "save_figure", keep)
    table4_heldout.plot(rows, tmp_path / "f.png")
    assert sorted(drawn) == sorted(f"{r['pipeline']}/{r['group']}" for r in rows)
    assert len(set(drawn.values())) == len(rows)
    assert figures.distinct_colors(3) == ["C0", "C1", "C2"]  # up to ten: matplotlib's own cycle, as before
    assert len({to_rgba(c) for c in figures.distinct_colors(20)}) == 20
    # each row has its own marker too: rows 11-13's tab20 shades were hard to tell from rows 1-3's
    assert len(set(markers.values())) == len(rows), markers
    # a row absent from the skill-vs-last-frame panels says why in its key (GenSim stacking's top camera: nothing moves)
    # (since its rerun of 2026-12-06 every committed row has moving pixels: one is made silent here, as it was)
    assert all(np.isfinite(r["one_step_moving_skill_last_10"]) for r in rows)
    i = next(i for i, r in enumerate(rows) if (r["pipeline"], r["group"]) == ("gensim", "stacking"))
    rows[i] = {k: (float("nan") if ("moving" in k or "object" in k) and ("skill" in k or "one_step" in k) else v)
               for k, v in rows[i].items()}
    keys.clear()
    table4_heldout.plot(rows, tmp_path / "f.png")
    # every committed row fails the gate at every count (simeval.measures.dynamics_diversity.gate), and its key says so
    expected = ("gensim/stacking [pixels: no reading at 10/20/40] (second and fourth panels: no reading, under 100 "
                "pixels moved)")
    assert [k for k in keys if "panel" in k] == [expected]
    rows[0] = {k: v for k, v in rows[0].items() if "moving" not in k}  # runs from before moving pixels were summed
    keys.clear()
    table4_heldout.plot(rows, tmp_path / "f.png")
    assert (f"{rows[0]['pipeline']}/{rows[0]['group']} [pixels: no reading at 10/20/40] (fourth panel: its runs did "
            "not sum moving pixels)") in keys


def test_the_heldout_figure_of_states_only_rows_is_the_state_panel_and_rows_sharing_a_group_name_their_preset(
        monkeypatch, tmp_path):
    """A fresh-clone trial's figures: a states-only sweep drew three empty pixel panels beside its one reading; a
    tiny sweep kept beside the committed rows gave two keys "robogen/table_top"; the open-loop style was keyed in a
    figure with no open-loop line."""
    from simeval.writing import figures
    from simeval.measures.dynamics_diversity import table4_heldout

    rows = table4_heldout.read_rows(ROOT / "outputs" / "tables" / "table4_heldout.csv")
    saved = {}

    def keep(fig, path, **kwargs):
        saved.update(titles=[ax.get_title() for ax in fig.axes if ax.axison],
                     rows=[t.get_text() for t in fig.legends[0].get_texts()],
                     styles=[t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()])
        return path

    monkeypatch.setattr(figures, "save_figure", keep)
    states_only = [{k: v for k, v in r.items() if k in ("pipeline", "group", "counts") or k.startswith("state")}
                   for r in rows[:2]]  # as a sweep of protocol.pixels=false gives them
    assert not any(table4_heldout.has_pixels(r) for r in states_only)
    table4_heldout.plot(states_only, tmp_path / "f.png")
    assert len(saved["titles"]) == 1 and saved["titles"][0].startswith("state reading")
    assert "model, open loop (skill panels)" not in saved["styles"]

    tiny = {**rows[-1], "preset": "tiny", "steps": 40}
    table4_heldout.plot([rows[-1], tiny], tmp_path / "f.png")
    name = f"{rows[-1]['pipeline']}/{rows[-1]['group']}"
    assert [k.split(" [")[0] for k in saved["rows"]] == [f"{name} ({rows[-1]['preset']}, {rows[-1]['steps']} steps)",
                                                         f"{name} (tiny, 40 steps)"]
    assert "model, open loop (skill panels)" in saved["styles"]  # the committed rows have open-loop lines


def test_a_wide_interval_is_cut_at_the_panel_edge_and_named_instead_of_squeezing_the_other_rows():
    """By hand: points -0.5 .. 0.7 (spread 1.2, pad 0.15 -> -0.68 .. 0.88); b's interval reaches -1.7 and is cut,
    a's highest end 0.75 sets the top; 4% of the span (1.43) above and below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simeval.writing.figures import cut_wide_intervals

    fig, ax = plt.subplots()
    a = ("a", [0.5, 0.7], [0.45, 0.65], [0.55, 0.75])
    b = ("b", [-0.5], [-1.7], [0.1])
    b_open_loop = ("b", [-0.3], [-0.9], [0.2])  # the same row's second line: one entry, its lowest end
    assert cut_wide_intervals(ax, [a, b, b_open_loop]) == ["b down to -1.70"]
    assert ax.get_ylim() == pytest.approx((-0.68 - 0.0572, 0.75 + 0.0572))
    fig2, ax2 = plt.subplots()
    ax2.plot([0, 1], [0.4, 0.8])
    before = ax2.get_ylim()
    assert cut_wide_intervals(ax2, [a]) == [] and ax2.get_ylim() == before  # every interval fits: as drawn
    plt.close(fig)
    plt.close(fig2)


def test_a_figure_save_that_stops_midway_leaves_the_previous_figure_whole(tmp_path):
    """A report killed while matplotlib wrote a PDF left a 0-byte table5.pdf (over a committed one with
    overwrite=true): the figure is written beside its path and renamed over it only once complete."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simeval.writing.figures import save_figure

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    target = tmp_path / "f.pdf"
    target.write_bytes(b"the committed figure")

    def stops_midway(path, **kwargs):
        Path(path).write_bytes(b"%PDF-1.4 half")
        raise KeyboardInterrupt

    real = fig.savefig
    fig.savefig = stops_midway
    with pytest.raises(KeyboardInterrupt):
        save_figure(fig, target)
    assert target.read_bytes() == b"the committed figure"
    assert [p.name for p in tmp_path.iterdir()] == ["f.pdf"]  # nothing half-written left beside it
    fig.savefig = real
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    host = socket.gethostname().split(".")[0]
    left = tmp_path / f".f.pdf.{int(dead.stdout)}@{host}.k2x9.tmp"  # what a run killed -9 mid-save leaves
    left.write_bytes(b"")
    alive = tmp_path / f".f.pdf.{os.getppid()}@{host}.a1b2.tmp"  # a live process may be saving the same figure
    alive.write_bytes(b"")
    elsewhere = tmp_path / f".f.pdf.{int(dead.stdout)}@not-{host}.c3d4.tmp"  # a shared folder: pid not ours to ask
    elsewhere.write_bytes(b"")
    assert save_figure(fig, target) == target and target.read_bytes().startswith(b"%PDF")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, elsewhere.name, "f.pdf"])
    plt.close(fig)


def test_a_kept_table_given_without_brackets_is_one_path():
    """`report.keep=outputs/tables/table5.csv` reached the builders as a string and was read one character at a
    time (the error named a file "o")."""
    from simeval.report.rebuild import kept_paths

    assert kept_paths({"keep": "outputs/tables/table5.csv"}) == ["outputs/tables/table5.csv"]
    assert kept_paths({"keep": ["a.csv", "b.csv"]}) == ["a.csv", "b.csv"]
    assert kept_paths({"keep": None}) == [] and kept_paths({}) == []


def test_a_gated_count_whose_skill_vs_the_last_frame_is_undefined_says_why_in_its_gate_cell():
    """Under 100 kept pixels moved: the table shows '—' for the skill against the last frame, and the gate's cell
    said "does not beat the last frame (skill -7282...)" beside it (a fresh-clone trial's tiny row). The run's gate
    and the table's read the same sums (gate_of_sums): by hand, a model 10x a near-exact copy's error."""
    import numpy as np

    from simeval.measures.dynamics_diversity.gate import gate_of_sums

    sums = {"model": np.full((2, 4), 10.0), "last": np.full((2, 4), 1.0), "mean": np.full((2, 4), 5.0)}
    quoted = gate_of_sums(sums, ["a", "a", "b", "b"])  # no moving pixels summed: the gate's own words
    assert not quoted["passes"] and "does not beat the last frame (skill -9" in quoted["verdict"]
    for moved, says_why in ((12.0, True), (13.0, False)):  # 8 episode-runs: 96 moved (under 100), then 104
        g = gate_of_sums({**sums, "moving": np.full((2, 4), moved)}, ["a", "a", "b", "b"])
        assert not g["passes"] and (g["verdict"] == "no reading: under 100 kept pixels moved (the last frame is a "
                                    "near-exact copy; no skill against it is defined)") == says_why


def test_the_heldout_figures_title_gives_the_gates_reason_too_few_pixels_moved_where_a_row_has_it(monkeypatch,
                                                                                                    tmp_path):
    from simeval.writing import figures
    from simeval.measures.dynamics_diversity import table4_heldout

    rows = table4_heldout.read_rows(ROOT / "outputs" / "tables" / "table4_heldout.csv")
    titles = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path, **kw: titles.append(fig._suptitle.get_text()))
    table4_heldout.plot(rows, tmp_path / "f.png")
    rows[0]["gate_10"] = ("no reading: under 100 kept pixels moved (the last frame is a near-exact copy; no skill "
                          "against it is defined)")
    table4_heldout.plot(rows, tmp_path / "f.png")
    assert "the model does not beat the last frame or the mean image;" in titles[0]
    assert "the model does not beat the last frame or the mean image, or under 100 kept pixels moved;" in titles[1]
