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
here); the runs under --root still have to exist, and a cell they have replaces the kept one. With --protocol
heldout (`--keep outputs/tables/table4_heldout.csv`) the unit is a row, one sweep's counts: a group with runs under
--root replaces its kept row whole (its intervals are drawn over all its counts together).
"""

from __future__ import annotations

import sys
from pathlib import Path

from simeval.cli import OneLineParser

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> None:
    ap = OneLineParser(description="Paper Table 4 (world-model eval error at 10/20/40 training episodes per "
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
    from simeval.errors import UserError
    from simeval.report.rebuild import rebuild_table4, rebuild_table4_heldout

    name = "table4_heldout" if a.protocol == "heldout" else "table4"
    out = a.out or str(ROOT / "outputs" / "tables" / name)
    figure = a.figure or str(ROOT / "outputs" / "figures" / f"{name}.png")
    try:
        if a.protocol == "heldout":
            done = rebuild_table4_heldout(a.root, out, figure, keep=a.keep, overwrite=a.overwrite)
        else:
            try:
                episodes = [int(x) for x in a.episodes.split(",")]
            except ValueError:
                raise UserError(f"--episodes {a.episodes}: expected 3 whole numbers separated by commas, e.g. "
                                "10,20,40") from None
            done = rebuild_table4(a.root, out, figure, episodes=episodes, preset=a.preset, keep=a.keep,
                                  overwrite=a.overwrite, flags={"episodes": "--episodes"})
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    print(done.markdown)
    for note in done.notes:
        print(f"note: {note}")
    print("wrote", ", ".join(str(p) for p in done.written))


if __name__ == "__main__":
    main()
