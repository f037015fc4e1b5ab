"""Rebuild every table and figure from the result.json files on disk, rerunning nothing (`make report`).

    python experiments/report_all.py                       # the folders `make table3/table4/table5` write
    python experiments/report_all.py --only table4,table5 --table4-runs outputs/paper/quick/table4 ...

Steps, each with the same library calls as its own command:
    table3   Table 3 (text diversity)    as src/report.py report=table3             tables/table3*.{csv,md,tex}
    table4   Table 4 (world models)      as src/report.py report=table4             tables/table4.*, figures/table4.*
    table5   Table 5 (Diffusion Policy)  as src/report.py report=table5             tables/table5*.*, figures/table5.*
    figure4  Figure 4 (quality)          as src/report.py report=figure4            figures/figure4.{png,pdf,md,...}
    html     the HTML report             as src/report.py report=html               <html-runs>/report/index.html
(tables: .csv, .md and .tex; figures: .png and .pdf)
A step never replaces a table or figure that git tracks (the committed results) unless --overwrite (`make report
OVERWRITE=1`): it says which file and is not rebuilt, like a step that fails on its inputs. A step whose inputs are
missing (no result.json of its metric; for Figure 4, no quality run scored by a model
judge) prints one line saying what to run and is skipped; the others still run. A step that fails on its inputs
(an unreadable result.json, two runs of one cell with different settings) prints one line and the command exits
with status 2 after the remaining steps.
"""

from __future__ import annotations

import sys
from pathlib import Path

from simeval.cli import OneLineParser

ROOT = Path(__file__).resolve().parents[1]

STEPS = ("table3", "table4", "table5", "figure4", "html")
OVERWRITE_FLAG = "--overwrite (make report OVERWRITE=1)"  # how a step's refusal tells the user to replace a file


class Skip(Exception):
    """A step's inputs are not there: a note, not an error."""


def _records(root: Path, metric: str, make: str) -> list[dict]:
    from simeval.results import read_results

    records = read_results(root, metric) if root.is_dir() else []
    if not records:
        raise Skip(f"no {metric} result.json under {root} ({make})")
    return records


def _refuse_committed(a, paths: list[Path]) -> None:
    """Before a step writes: those of its files that git tracks stop it unless --overwrite."""
    from simeval.report.tables import refuse_committed

    refuse_committed(paths, a.overwrite, OVERWRITE_FLAG)


def table3(a) -> list[Path]:
    import yaml

    from simeval.report.build import build_text_diversity_report

    runs = Path(a.table3_runs)
    _records(runs, "text_diversity", "`make table3` runs the sweep")
    spec = yaml.safe_load((ROOT / "conf" / "report" / "table3.yaml").read_text())
    from simeval.report.tables import outputs_named

    _refuse_committed(a, outputs_named(a.tables, spec["id"]))
    written = build_text_diversity_report(runs, a.tables, id=spec["id"], rows=spec["rows"], columns=spec["columns"],
                                          caption=spec.get("caption", ""), statistic=spec.get("statistic", "div"),
                                          digits=spec.get("digits", 2))
    return [p for paths in written.values() for p in paths]


def table4(a) -> list[Path]:
    from simeval.report import table4 as t4
    from simeval.report.rebuild import rebuild_table4

    _records(Path(a.table4_runs), t4.METRIC, "`make table4` trains the world models")
    done = rebuild_table4(a.table4_runs, Path(a.tables) / "table4", Path(a.figures) / "table4.png",
                          episodes=[int(x) for x in a.table4_episodes.split(",")], overwrite=a.overwrite,
                          flags={"episodes": "--table4-episodes", "overwrite": OVERWRITE_FLAG})
    for note in done.notes:
        print(f"Table 4: note: {note}")
    return done.written


def table5(a) -> list[Path]:
    from simeval.report import table5 as t5

    _records(Path(a.table5_runs), t5.METRIC, "`make table5` trains and rolls out the policies")
    return t5.rebuild_table5(a.table5_runs, Path(a.tables) / "table5", Path(a.figures) / "table5.png",
                             policy=a.table5_policy, overwrite=a.overwrite, overwrite_flag=OVERWRITE_FLAG).written


def figure4(a) -> list[Path]:
    from simeval.report.quality_figure import build_quality_figure, quality_points

    runs = Path(a.quality_runs)
    records = _records(runs, "quality", "run src/quality.py with a model judge, see README")
    if all(r.get("judge") == "oracle" for r in records):
        raise Skip(f"the quality runs under {runs} are scored by the oracle judge only, and Figure 4 plots a model "
                   "judge's scene alignment: run src/quality.py judge=openai (see README) on those episodes")
    if not any(p["scene_alignment"] is not None and p["task_completion"] is not None
               for p in quality_points(records)):
        raise Skip(f"no quality run under {runs} has both scene_alignment and task_completion scores (run "
                   "src/quality.py metric=all)")
    from simeval.report.tables import outputs_named

    _refuse_committed(a, outputs_named(a.figures, "figure4"))
    written = build_quality_figure(runs, a.figures, id="figure4")
    return [p for paths in written.values() for p in paths]


def html(a) -> list[Path]:
    from simeval.report.html import build_html_report

    runs = Path(a.html_runs)
    if not runs.is_dir():
        raise Skip(f"no folder {runs} (give the runs to report on: make report RUNS=<run or sweep folder>)")
    return [build_html_report(runs, a.html_out, tables_dir=a.tables, figures_dir=a.figures)]


TITLES = {"table3": "Table 3", "table4": "Table 4", "table5": "Table 5", "figure4": "Figure 4", "html": "HTML report"}


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(STEPS), help=f"comma-separated steps of {', '.join(STEPS)}")
    ap.add_argument("--table3-runs", default="outputs/table3/runs")
    ap.add_argument("--table4-runs", default="outputs")
    ap.add_argument("--table4-episodes", default="10,20,40",
                    help="our training-episode counts in the paper's 10/20/40 columns (quick profile: 1,2,4)")
    ap.add_argument("--table5-runs", default="outputs")
    ap.add_argument("--table5-policy", default=None, help="only policy runs of this preset (default: a row per preset)")
    ap.add_argument("--quality-runs", default="outputs/runs/quality")
    ap.add_argument("--html-runs", default="outputs/runs")
    ap.add_argument("--html-out", default=None, help="default: <html-runs>/report")
    ap.add_argument("--tables", default="outputs/tables")
    ap.add_argument("--figures", default="outputs/figures")
    ap.add_argument("--overwrite", action="store_true", help="replace tables and figures that git tracks (default: "
                                                             "refuse, one line per step)")
    a = ap.parse_args(argv)
    from simeval.errors import UserError

    steps = [s for s in a.only.split(",") if s]
    unknown = [s for s in steps if s not in STEPS]
    if unknown:
        print(f"error: --only {a.only}: unknown step {unknown[0]!r}; steps: {', '.join(STEPS)}", file=sys.stderr)
        return 2
    failed = []
    for step in steps:
        try:
            written = globals()[step](a)
        except Skip as e:
            print(f"{TITLES[step]}: skipped: {e}", flush=True)
            continue
        except UserError as e:
            print(f"{TITLES[step]}: error: {str(e).strip().splitlines()[0]}", file=sys.stderr, flush=True)
            failed.append(step)
            continue
        print(f"{TITLES[step]}: " + ", ".join(str(p) for p in written), flush=True)
    if failed:
        print(f"error: {', '.join(TITLES[s] for s in failed)} not rebuilt (see above); the others were",
              file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
