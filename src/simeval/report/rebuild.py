"""Tables 4 and 5 rebuilt from the result.json files on disk, as plain functions: the one place the report door
(`src/report.py report=table4|table4_heldout|table5`, which the make targets call) and `make report`
(experiments/report_all.py) call.

    rebuild_table4(root, out, figure, episodes=(10, 20, 40), preset=None, keep=(), overwrite=False) -> Rebuilt
    rebuild_table4_heldout(root, out, figure, keep=(), overwrite=False) -> Rebuilt
    rebuild_table5(root, out, figure, policy=None, keep=(), overwrite=False) -> Rebuilt   (simeval.report.table5)
Each reads every result.json of its metric under `root` (none: a UserError saying what makes them), refuses to
replace files git tracks unless `overwrite` (simeval.report.tables.refuse_committed), writes the tables at `out`
(a path without suffix) and the figure at `figure` (.png; a .pdf beside it for Tables 4 and 5), and returns what it
wrote with the Markdown table and notes to print. `keep`: CSVs of earlier tables whose rows the runs on disk lack
are kept (groups run on other machines).
"""

from __future__ import annotations

from pathlib import Path

from simeval.errors import UserError
from simeval.report.tables import Rebuilt, refuse_committed
from simeval.report.table5 import rebuild_table5
from simeval.results import read_results

__all__ = ["Rebuilt", "rebuild", "rebuild_table4", "rebuild_table4_heldout", "rebuild_table5"]


def _with(stem: str | Path, suffixes: tuple[str, ...]) -> list[Path]:
    return [Path(f"{stem}{s}") for s in suffixes]


def rebuild_table4(root: str | Path, out: str | Path, figure: str | Path, *, episodes=(10, 20, 40),
                   preset: str | None = None, keep=(), overwrite: bool = False, flags: dict | None = None) -> Rebuilt:
    """`flags`: how the caller's user spells `episodes` and `overwrite` ({"episodes": "report.episodes", ...}), named in
    the note about unused runs and in the refusal to replace a committed file."""
    from simeval.report import table4

    flags = {"episodes": "episodes", "overwrite": "--overwrite", **(flags or {})}

    episodes = [int(k) for k in episodes]
    kept = [table4.read_rows(path) for path in keep]  # read first: a bad file fails before any work
    records = read_results(root, metric=table4.METRIC)
    if not records:  # with keep too: a mistyped root must not pass for "nothing new"
        raise UserError(f"no {table4.METRIC} result.json under {root}: run the world models first "
                        "(make table4, or src/diversity.py), or give the folder that holds them")
    refuse_committed([*_with(Path(out), (".csv", ".md", ".tex")), *(Path(figure).with_suffix(x) for x in
                                                                      (".png", ".pdf"))], overwrite, flags["overwrite"])
    presets = sorted({str(r["identity"].get("preset")) for r in records})
    if preset and preset not in presets:
        raise UserError(f"preset {preset}: no {table4.METRIC} run of that preset under {root} (its runs' presets: "
                        f"{', '.join(presets)})")
    rows = table4.build(records, episodes=episodes, preset=preset)
    for rows_of_file in kept:
        rows = table4.merge([r for r in rows_of_file if not preset or r["preset"] in ("", preset)], rows, episodes)
    unused = table4.unused_episodes(records, episodes)
    written = table4.write(rows, out, episodes, unused)
    figures = table4.plot(rows, figure)
    notes = [f"runs trained on {', '.join(map(str, unused))} episodes per task are not in the table "
             f"({flags['episodes']} {','.join(map(str, episodes))} chose its columns)"] if unused else []
    return Rebuilt([*written.values(), *figures], written["md"].read_text(), notes)


def rebuild_table4_heldout(root: str | Path, out: str | Path, figure: str | Path, *, keep=(),
                           overwrite: bool = False, overwrite_flag: str = "--overwrite") -> Rebuilt:
    from simeval.report import table4_heldout

    kept = [table4_heldout.read_rows(path) for path in keep]  # read first: a bad file fails before any work
    records = [r for r in read_results(root, metric=table4_heldout.METRIC)
               if (r.get("identity") or {}).get("protocol") == "heldout"]
    if not records:
        raise UserError(f"no protocol=heldout {table4_heldout.METRIC} result.json under {root}: run "
                        "src/diversity.py (protocol=heldout is its default) first, or give the folder that holds them")
    out, figure = Path(out), Path(figure)
    refuse_committed([out.with_suffix(".csv"), out.with_suffix(".md"), figure], overwrite, overwrite_flag)
    rows = table4_heldout.build(records)
    for rows_of_file in kept:  # the rows merged so far win: the first file that has a row gives it
        rows = table4_heldout.merge(rows_of_file, rows)
    written = table4_heldout.write(rows, out)
    table4_heldout.plot(rows, figure, "held-out prediction (protocol=heldout)")
    return Rebuilt([*written.values(), figure], written["md"].read_text())


KINDS = ("table3", "figure4", "table4", "table4_heldout", "table5", "html")


def rebuild(spec: dict, overwrite: bool = False) -> Rebuilt:
    """One report of conf/report/<kind>.yaml (`spec`, resolved): its `kind` picks the builder."""
    kind = spec.get("kind")
    flag = "overwrite=true (make: OVERWRITE=1)"  # how a user of the door, or of its make targets, asks to replace one
    if kind == "table4":
        return rebuild_table4(spec["runs_dir"], spec["out"], spec["figure"],
                              episodes=spec.get("episodes", (10, 20, 40)), preset=spec.get("preset"),
                              keep=spec.get("keep") or (), overwrite=overwrite,
                              flags={"episodes": "report.episodes", "overwrite": flag})
    if kind == "table4_heldout":
        return rebuild_table4_heldout(spec["runs_dir"], spec["out"], spec["figure"], keep=spec.get("keep") or (),
                                      overwrite=overwrite, overwrite_flag=flag)
    if kind == "table5":
        return rebuild_table5(spec["runs_dir"], spec["out"], spec["figure"], policy=spec.get("policy"),
                              keep=spec.get("keep") or (), overwrite=overwrite, overwrite_flag=flag)
    if kind == "html":
        from simeval.report.html import build_html_report

        page = build_html_report(spec["runs_dir"], spec.get("out_dir"), tables_dir=spec.get("tables_dir"),
                                 figures_dir=spec.get("figures_dir"), title=spec.get("title", "simeval report"))
        return Rebuilt([page], f"HTML report: {page} (open it in a browser; the folder is self-contained)")
    if kind not in ("table3", "figure4"):
        raise UserError(f"report.kind={kind!r}: expected one of {', '.join(KINDS)}")
    from simeval.report.tables import outputs_named

    if read_results(spec["runs_dir"], spec["metric"]):  # without runs, the builder's own error says what to run
        refuse_committed(outputs_named(spec["out_dir"], spec["id"]), overwrite, flag)
    if kind == "figure4":
        from simeval.report.quality_figure import build_quality_figure

        written = build_quality_figure(spec["runs_dir"], spec["out_dir"], id=spec["id"])
        return Rebuilt([p for paths in written.values() for p in paths], Path(written["table"][1]).read_text())
    from simeval.report.build import build_text_diversity_report

    written = build_text_diversity_report(
        spec["runs_dir"], spec["out_dir"], id=spec["id"], rows=spec["rows"], columns=spec["columns"],
        caption=spec.get("caption", ""), statistic=spec.get("statistic", "div"), digits=spec.get("digits", 2))
    return Rebuilt([p for paths in written.values() for p in paths], Path(written["main"][1]).read_text())
