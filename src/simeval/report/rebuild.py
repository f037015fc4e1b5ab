"""Tables and figures rebuilt from the result.json files on disk, as plain functions: what the report door
(`src/report.py report=table3|figure4|table4|table4_heldout|table5|html|all`, which the make targets call) calls.

    rebuild_table4(root, out, figure, episodes=(10, 20, 40), preset=None, keep=(), overwrite=False) -> Rebuilt
    rebuild_table4_heldout(root, out, figure, keep=(), overwrite=False) -> Rebuilt
    rebuild_table5(root, out, figure, policy=None, keep=(), overwrite=False) -> Rebuilt   (simeval.measures.generalization.table5)
Each reads every result.json of its metric under `root` (none: a UserError saying what makes them), refuses to
replace files git tracks unless `overwrite` (simeval.writing.tables.refuse_committed), writes the tables at `out`
(a path without suffix) and the figure at `figure` (.png; a .pdf beside it for Tables 4 and 5), and returns what it
wrote with the Markdown table and notes to print. `keep`: CSVs of earlier tables whose rows the runs on disk lack
are kept (groups run on other machines). Tables 4 (held-out) and 5 take `root=None` (`report.runs_dir=null`):
drawn again from the kept CSVs alone, after a change to the plotting code or on a clone without the runs.

    rebuild(spec, overwrite=False) -> Rebuilt          one report of conf/report/<kind>.yaml
    rebuild_all(spec, overwrite=False) -> list of the steps that failed   (report=all, `make report`)
"""

from __future__ import annotations

from pathlib import Path

from simeval.errors import UserError
from simeval.writing.tables import (Rebuilt, ReportWords, kept_only_hint, read_kept, refuse_committed, replaced_notes,
                                    rows_lost)
from simeval.measures.generalization.table5 import rebuild_table5
from simeval.results import read_results

__all__ = ["Rebuilt", "rebuild", "rebuild_table4", "rebuild_table4_heldout", "rebuild_table5"]


def _with(stem: str | Path, suffixes: tuple[str, ...]) -> list[Path]:
    return [Path(f"{stem}{s}") for s in suffixes]


def rebuild_table4(root: str | Path, out: str | Path, figure: str | Path, *, episodes=(10, 20, 40),
                   preset: str | None = None, keep=(), overwrite: bool = False,
                   words: ReportWords = ReportWords()) -> Rebuilt:
    """`words`: how the caller's user asks to replace a committed file, to write elsewhere, to choose the columns
    and to keep earlier rows, named in the refusal and in notes."""
    from simeval.measures.dynamics_diversity import table4

    episodes = [int(k) for k in episodes]
    kept = read_kept(table4.read_rows, keep, words.keep, "Table 4")
    records = read_results(root, metric=table4.METRIC)
    if not records:  # with keep too: a mistyped root must not pass for "nothing new"
        raise UserError(f"no {table4.METRIC} result.json under {root}: run the world models first "
                        "(make table4, or src/diversity.py), or give the folder that holds them")
    presets = sorted({str(r["identity"].get("preset")) for r in records})
    if preset and preset not in presets:
        raise UserError(f"preset {preset}: no {table4.METRIC} run of that preset under {root} (its runs' presets: "
                        f"{', '.join(presets)})")
    rows = table4.build(records, episodes=episodes, preset=preset)
    for rows_of_file in kept:
        rows = table4.merge([r for r in rows_of_file if not preset or r["preset"] in ("", preset)], rows, episodes)
    lost = rows_lost(Path(out).with_suffix(".csv"), keep, [r for r in rows if r["preset"]], table4.read_rows,
                     lambda r: (r["pipeline"], r["group"], r["preset"]) if r["preset"] else None, words.keep)
    replaced = [*_with(Path(out), (".csv", ".md", ".tex")), *_with(Path(figure).with_suffix(""), (".png", ".pdf"))]
    refuse_committed(replaced, overwrite, words.overwrite, words.elsewhere, lost=lost)
    unused = table4.unused_episodes(records, episodes)
    written = table4.write(rows, out, episodes, unused)
    figures = table4.plot(rows, figure)
    notes = [f"runs trained on {', '.join(map(str, unused))} episodes per task are not in the table "
             f"({words.episodes} {','.join(map(str, episodes))} chose its columns)"] if unused else []
    notes += replaced_notes(lost)
    return Rebuilt([*written.values(), *figures], written["md"].read_text(), notes)


def rebuild_table4_heldout(root: str | Path | None, out: str | Path, figure: str | Path, *, keep=(),
                           overwrite: bool = False, words: ReportWords = ReportWords()) -> Rebuilt:
    from simeval.measures.dynamics_diversity import table4_heldout

    kept = read_kept(table4_heldout.read_rows, keep, words.keep, "held-out Table 4")
    records = [] if root is None else [r for r in read_results(root, metric=table4_heldout.METRIC)
                                       if (r.get("identity") or {}).get("protocol") == "heldout"]
    if not records and root is not None:
        raise UserError(f"no protocol=heldout {table4_heldout.METRIC} result.json under {root}: run "
                        "src/diversity.py (protocol=heldout is its default) first, or give the folder that holds them"
                        + kept_only_hint(keep, words.keep, Path(out).with_suffix(".csv")))
    out, figure = Path(out), Path(figure)
    rows = table4_heldout.build(records)
    for rows_of_file in kept:  # the rows merged so far win: the first file that has a row gives it
        rows = table4_heldout.merge(rows_of_file, rows)
    lost = rows_lost(out.with_suffix(".csv"), keep, rows, table4_heldout.read_rows,
                     lambda r: tuple(str(r.get(c)) for c in table4_heldout.ROW_KEY), words.keep)
    refuse_committed([out.with_suffix(".csv"), out.with_suffix(".md"), figure], overwrite, words.overwrite,
                     words.elsewhere, source="the kept tables alone" if root is None else "the runs on disk",
                     lost=lost)
    written = table4_heldout.write(rows, out)
    table4_heldout.plot(rows, figure, "held-out prediction (protocol=heldout)")
    return Rebuilt([*written.values(), figure], written["md"].read_text(),
                   replaced_notes(lost))


KINDS = ("table3", "figure4", "table4", "table4_heldout", "table5", "html", "all")
STEPS = {"table3": "Table 3", "table4": "Table 4", "table4_heldout": "Table 4 (held-out)", "table5": "Table 5",
         "figure4": "Figure 4", "html": "HTML report"}  # report=all's steps, in the order they run, and their titles


def kept_paths(spec: dict) -> list:
    """`spec`'s keep as a list of paths: `report.keep=a.csv` (no brackets) is one path, not its characters."""
    keep = spec.get("keep") or ()
    return [keep] if isinstance(keep, str | Path) else list(keep)


def rebuild(spec: dict, overwrite: bool = False, key: str = "report") -> Rebuilt:
    """One report of conf/report/<kind>.yaml (`spec`, resolved): its `kind` picks the builder. `key`: where the
    user's config holds `spec` (report=all's steps: report.<step>), for the keys a note names."""
    from simeval.report.specs import check_report

    check_report(spec, key)
    kind = spec.get("kind")
    if spec.get("runs_dir") is None:
        check_kept_only(spec, key)
    elif kind in MAKERS:  # the html kind says itself what it wants of its folder
        check_runs_dir(Path(spec["runs_dir"]), key, kind)
    flag = "overwrite=true (make: OVERWRITE=1)"  # how a user of the door, or of its make targets, asks to replace one
    elsewhere = f"{key}.out= and {key}.figure=" if kind in ("table4", "table4_heldout", "table5") else f"{key}.out_dir="
    words = ReportWords(overwrite=flag, elsewhere=elsewhere, keep=f"{key}.keep", episodes=f"{key}.episodes")
    if kind == "table4":
        return rebuild_table4(spec["runs_dir"], spec["out"], spec["figure"],
                              episodes=spec.get("episodes", (10, 20, 40)), preset=spec.get("preset"),
                              keep=kept_paths(spec), overwrite=overwrite, words=words)
    if kind == "table4_heldout":
        return rebuild_table4_heldout(spec["runs_dir"], spec["out"], spec["figure"], keep=kept_paths(spec),
                                      overwrite=overwrite, words=words)
    if kind == "table5":
        return rebuild_table5(spec["runs_dir"], spec["out"], spec["figure"], policy=spec.get("policy"),
                              keep=kept_paths(spec), overwrite=overwrite, words=words)
    if kind == "html":
        from simeval.report.html import build_html_report

        page = build_html_report(spec["runs_dir"], spec.get("out_dir"), tables_dir=spec.get("tables_dir"),
                                 figures_dir=spec.get("figures_dir"), title=spec.get("title", "simeval report"))
        return Rebuilt([page], f"HTML report: {page} (open it in a browser; the folder is self-contained)")
    if kind not in ("table3", "figure4"):
        raise UserError(f"{key}.kind={kind!r}: expected one of {', '.join(k for k in KINDS if k != 'all')}")
    from simeval.writing.tables import outputs_named

    if read_results(spec["runs_dir"], spec["metric"]):  # without runs, the builder's own error says what to run
        refuse_committed(outputs_named(spec["out_dir"], spec["id"]), overwrite, flag, elsewhere)
    if kind == "figure4":
        from simeval.measures.quality.figure4 import build_quality_figure

        written = build_quality_figure(spec["runs_dir"], spec["out_dir"], id=spec["id"])
        return Rebuilt([p for paths in written.values() for p in paths], Path(written["table"][1]).read_text())
    from simeval.measures.text_diversity.artefacts import build_text_diversity_report

    written = build_text_diversity_report(
        spec["runs_dir"], spec["out_dir"], id=spec["id"], rows=spec["rows"], columns=spec["columns"],
        caption=spec.get("caption", ""), statistic=spec.get("statistic", "div"), digits=spec.get("digits", 2))
    return Rebuilt([p for paths in written.values() for p in paths], Path(written["main"][1]).read_text())


MAKERS = {"table3": ("text_diversity", "`make table3` runs the sweep"),
          "table4": ("dynamics_diversity", "`make table4` trains the world models"),
          "table4_heldout": ("dynamics_diversity", "`make table4-heldout`, or src/diversity.py: its default protocol"),
          "table5": ("generalization", "`make table5` trains and rolls out the policies"),
          "figure4": ("quality", "run src/quality.py with a model judge, see README")}  # step -> (metric, its maker)


KEPT_ONLY = ("table4_heldout", "table5")  # the reports that can be drawn again from their own CSVs (runs_dir=null)


def check_kept_only(spec: dict, key: str) -> None:
    """`runs_dir: null` asks for the tables and figure drawn again from `keep`'s CSVs alone (after a change to the
    plotting code, on a clone without the runs): said on purpose, so not mistaken for an empty folder. One
    UserError where that cannot be done."""
    kind = spec.get("kind")
    if kind not in KEPT_ONLY:
        raise UserError(f"{key}.runs_dir=null: only report={' and report='.join(KEPT_ONLY)} can be drawn from their "
                        f"kept tables alone; give {key}.runs_dir=<the folder that holds the runs>")
    if not kept_paths(spec):
        raise UserError(f"{key}.runs_dir=null draws from {key}.keep's tables alone, and it is empty; give "
                        f"{key}.keep=[outputs/tables/{kind}.csv] (or a folder of runs)")


def check_runs_dir(runs: Path, key: str, kind: str) -> None:
    """A runs folder that is a file or does not exist is one UserError naming `key`.runs_dir (the single-report door
    and report=all say the same), with what makes the runs."""
    if runs.exists() and not runs.is_dir():
        raise UserError(f"{key}.runs_dir={runs}: is a file, not a folder of runs; give the folder that holds the "
                        "runs' result.json files")
    if not runs.exists():
        maker = f" ({MAKERS[kind][1]})" if kind in MAKERS else ""
        raise UserError(f"{key}.runs_dir={runs}: no such folder; give the folder that holds the runs' result.json "
                        f"files{maker}")


def missing_inputs(step: str, spec: dict, made_under: str | Path | None = None) -> str | None:
    """Why report=all's `step` has nothing to build from (it is skipped, saying what makes its inputs), or None.
    A runs folder that does not exist is "nothing made yet" only under `made_under` (the project's outputs, where
    the commands write); elsewhere (a folder the user typed) it is a UserError, as is a file. A result.json that
    cannot be read is not "missing": the step runs and its builder names the file."""
    if spec.get("runs_dir") is None:  # from the kept tables alone: rebuild() checks that it can be
        return None
    runs = Path(spec["runs_dir"])
    if runs.exists() or made_under is None or not _inside(runs, Path(made_under)):  # not yet made: skipped below
        check_runs_dir(runs, f"report.{step}", step)
    if step == "html":
        return None if runs.is_dir() else (f"no folder {runs} yet (give the runs to report on: "
                                           "report.html.runs_dir=<run or sweep folder>; make: RUNS=)")
    metric, maker = MAKERS[step]
    records = read_results(runs, metric) if runs.is_dir() else []
    if step == "table4_heldout":
        records = [r for r in records if (r.get("identity") or {}).get("protocol") == "heldout"]
    if not records:
        return f"no {'protocol=heldout ' if step == 'table4_heldout' else ''}{metric} result.json under {runs} ({maker})"
    if step == "figure4":
        from simeval.measures.quality.figure4 import quality_points

        if all(r.get("judge") == "oracle" for r in records):
            return (f"the quality runs under {runs} are scored by the oracle judge only, and Figure 4 plots a model "
                    "judge's scene alignment: run src/quality.py judge=openai (see README) on those episodes")
        if not any(p["scene_alignment"] is not None and p["task_completion"] is not None
                   for p in quality_points(records)):
            return (f"no quality run under {runs} has both scene_alignment and task_completion scores (run "
                    "src/quality.py metric=all)")
    return None


def say_line(line: str) -> None:
    """A step's line of report=all, at once (a long step follows); the one error line of a step not written is the
    door's, on stderr."""
    print(line, flush=True)


def _inside(path: Path, folder: Path) -> bool:
    return path.resolve().is_relative_to(folder.resolve())


def rebuild_all(spec: dict, overwrite: bool = False, made_under: str | Path | None = None,
                say=say_line) -> list[str]:
    """report=all (`make report`): each step of `spec["steps"]` (STEPS) as its own report, with its settings at
    spec[step]. Says one line per step: what it wrote, or why it was skipped (no inputs: missing_inputs, with
    `made_under`), or why it was not written (a UserError: a result.json it cannot read, a committed file it would
    replace without `overwrite`, a runs folder that is not there), and goes on; returns the titles of the steps not
    written (the door then stops with one error line naming them, exit 2, after the others ran)."""
    steps = spec.get("steps")
    steps = [steps] if isinstance(steps, str) else list(steps or ())
    unknown = [s for s in steps if s not in STEPS]
    if unknown or not steps or len(set(steps)) < len(steps):
        why = (f"unknown step {unknown[0]!r}" if unknown else "empty" if not steps else
               f"{next(s for s in steps if steps.count(s) > 1)} twice")
        raise UserError(f"report.steps={steps}: {why}; give some of {', '.join(STEPS)}")
    failed = []
    for step in steps:
        title = STEPS[step]
        try:
            why = missing_inputs(step, spec[step], made_under)
            if why:
                say(f"{title}: skipped: {why}")
                continue
            done = rebuild(spec[step], overwrite, key=f"report.{step}")
        except UserError as e:
            say(f"{title}: not written: {str(e).strip().splitlines()[0]}")
            failed.append(title)
            continue
        for note in done.notes:
            say(f"{title}: note: {note}")
        say(f"{title}: " + ", ".join(map(str, done.written)))
    return failed
