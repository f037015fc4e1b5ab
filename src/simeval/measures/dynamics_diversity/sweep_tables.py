"""A dynamics-diversity sweep's own Table 4 and figure, written into the sweep's folder when it ends, so that
`python src/diversity.py pipeline=bbsea -m episodes=10,20,40` ends with its numbers in one table and one picture
(the committed tables under outputs/tables are never touched: simeval.writing.tables.refuse_committed).

    write_sweep_tables(sweep_dir) -> [written paths]
protocol=heldout runs: `<sweep>/table4_heldout.{csv,md}` and `table4_heldout.png` (simeval.measures.dynamics_diversity.table4_heldout:
prediction errors with baselines, skill and intervals over seeds and held-out episodes); protocol=paper runs:
`<sweep>/table4.{csv,md,tex}` and `table4.{png,pdf}` (simeval.measures.dynamics_diversity.table4) when the sweep has
exactly three episode counts (the paper's three columns), else a note. Runs that failed (status other than ok) are left
out.
"""

from __future__ import annotations

import logging
from pathlib import Path

from simeval.results import read_results

log = logging.getLogger(__name__)
METRIC = "dynamics_diversity"


def write_sweep_tables(sweep_dir: str | Path) -> list[Path]:
    from simeval.measures.dynamics_diversity import table4
    from simeval.measures.dynamics_diversity import table4_heldout

    sweep_dir = Path(sweep_dir)
    records = [r for r in read_results(sweep_dir, METRIC) if r.get("status", "ok") == "ok"]
    heldout = [r for r in records if (r.get("identity") or {}).get("protocol") == "heldout"]
    paper = [r for r in records if (r.get("identity") or {}).get("protocol", "paper") == "paper"]
    written: list[Path] = []
    if heldout:
        rows = table4_heldout.build(heldout)
        written += [*table4_heldout.write(rows, sweep_dir / "table4_heldout").values(),
                    table4_heldout.plot(rows, sweep_dir / "table4_heldout.png",
                                        "held-out prediction (protocol=heldout)")]
    if paper:
        counts = sorted({int(r["identity"]["episodes"]) for r in paper})
        if len(counts) == len(table4.EPISODES):
            rows = table4.build(paper, episodes=counts)
            written += [*table4.write(rows, sweep_dir / "table4", counts).values(),
                        *table4.plot(rows, sweep_dir / "table4.png")]
        else:
            log.info("protocol=paper runs on %s episodes per task: Table 4 has %d columns (e.g. -m "
                     "episodes=10,20,40); no table drawn", "/".join(map(str, counts)), len(table4.EPISODES))
    return written
