"""Paper Table 4 from the dynamics_diversity result.json files: eval error at 10/20/40 training episodes per
pipeline and group, the paper's values beside ours, and a plot of error against episodes (simeval.report.table4).

    python experiments/world_model_table4.py [--root outputs] [--preset cpu] [--episodes 10,20,40] [--keep CSV]
Writes outputs/tables/table4.{csv,md,tex} and outputs/figures/table4.{png,pdf}. Our numbers are the posterior image
error summed over pixels at our resolution (cpu preset: 64x64; the paper's: 128x128), so compare shapes (how the
error falls with episodes) and per-pixel values, not raw magnitudes. Runs of one cell with several seeds are
averaged. No dynamics_diversity result.json under --root: one line on stderr, exit status 2.
`--protocol heldout` tabulates the protocol=heldout runs instead (simeval.report.table4_heldout: held-out prediction
error with baselines, skill and intervals over seeds and episodes) into outputs/tables/table4_heldout.{csv,md} and
outputs/figures/table4_heldout.png. Neither protocol replaces tables or figures that git tracks (the committed ones)
unless --overwrite.
`--keep outputs/tables/table4.csv` (repeatable) extends an earlier table: its cells that the runs under --root lack
are kept (how the committed table gathers groups run on different machines, whose result.json files are not all
here); the runs under --root still have to exist, and a cell they have replaces the kept one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Paper Table 4 (world-model eval error at 10/20/40 training episodes per "
                                             "task group) from dynamics_diversity result.json files, with a figure.")
    ap.add_argument("--root", default=str(ROOT / "outputs"), help="folder searched for result.json files")
    ap.add_argument("--preset", default=None, help="only runs of this world_model preset")
    ap.add_argument("--out", default=None, help="tables, without suffix (default: outputs/tables/table4, or "
                                                 "table4_heldout with --protocol heldout)")
    ap.add_argument("--figure", default=None, help="the figure (.png; with --protocol paper a .pdf is written beside "
                                                   "it; default: outputs/figures/table4.png or table4_heldout.png)")
    ap.add_argument("--episodes", default="10,20,40",
                    help="our training-episode counts shown beside the paper's 10/20/40 (quick profile: 1,2,4)")
    ap.add_argument("--keep", action="append", default=[], metavar="CSV",
                    help="an earlier table's CSV whose cells the runs under --root lack are kept (runs made on another "
                         "machine); repeatable, the first file that has a cell gives it")
    ap.add_argument("--protocol", choices=["paper", "heldout"], default="paper",
                    help="which runs: the paper's (Table 4 as published) or simeval's held-out prediction protocol")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace tables or figures that git tracks (the committed Table 4; default: refuse)")
    a = ap.parse_args(argv)
    if a.protocol == "heldout":
        return heldout(a)
    a.out = a.out or str(ROOT / "outputs" / "tables" / "table4")
    a.figure = a.figure or str(ROOT / "outputs" / "figures" / "table4.png")
    from simeval.errors import UserError
    from simeval.report import table4
    from simeval.report.tables import refuse_committed
    from simeval.results import read_results

    try:
        try:
            episodes = [int(x) for x in a.episodes.split(",")]
        except ValueError:
            raise UserError(f"--episodes {a.episodes}: expected 3 whole numbers separated by commas, e.g. 10,20,40")
        kept = [table4.read_rows(path) for path in a.keep]  # read first: a bad file fails before any work
        records = read_results(a.root, metric=table4.METRIC)
        if not records:  # with --keep too: a mistyped --root must not pass for "nothing new"
            raise UserError(f"no {table4.METRIC} result.json under {a.root}: run the world models first "
                            "(make table4, or src/diversity.py), or give --root the folder that holds them")
        refuse_committed([*(Path(a.out).with_suffix(x) for x in (".csv", ".md", ".tex")),
                          *(Path(a.figure).with_suffix(x) for x in (".png", ".pdf"))], a.overwrite)
        presets = sorted({str(r["identity"].get("preset")) for r in records})
        if a.preset and a.preset not in presets:
            raise UserError(f"--preset {a.preset}: no {table4.METRIC} run of that preset under {a.root} (its runs' "
                            f"presets: {', '.join(presets)})")
        rows = table4.build(records, episodes=episodes, preset=a.preset)
        for rows_of_file in kept:
            rows = table4.merge([r for r in rows_of_file if not a.preset or r["preset"] in ("", a.preset)], rows,
                                episodes)
        unused = table4.unused_episodes(records, episodes)
        written = table4.write(rows, a.out, episodes, unused)
        figures = table4.plot(rows, a.figure)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    print(written["md"].read_text())
    if unused:
        print(f"note: runs trained on {', '.join(map(str, unused))} episodes per task are not in the table "
              f"(--episodes {a.episodes} chose its columns)")
    print("wrote", ", ".join(str(p) for p in [*written.values(), *figures]))


def heldout(a) -> None:
    from simeval.errors import UserError
    from simeval.report import table4_heldout
    from simeval.report.tables import refuse_committed
    from simeval.results import read_results

    stem = Path(a.out or ROOT / "outputs" / "tables" / "table4_heldout")
    figure = Path(a.figure or ROOT / "outputs" / "figures" / "table4_heldout.png")
    try:
        records = [r for r in read_results(a.root, metric=table4_heldout.METRIC)
                   if (r.get("identity") or {}).get("protocol") == "heldout"]
        if not records:
            raise UserError(f"no protocol=heldout {table4_heldout.METRIC} result.json under {a.root}: run "
                            "src/diversity.py (protocol=heldout is its default) first, or give --root their folder")
        refuse_committed([stem.with_suffix(".csv"), stem.with_suffix(".md"), figure], a.overwrite)
        rows = table4_heldout.build(records)
        written = table4_heldout.write(rows, stem)
        table4_heldout.plot(rows, figure, "held-out prediction (protocol=heldout)")
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    print(written["md"].read_text())
    print("wrote", ", ".join(str(p) for p in [*written.values(), figure]))


if __name__ == "__main__":
    main()
