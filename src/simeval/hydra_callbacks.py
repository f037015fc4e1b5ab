"""Hydra callbacks (hydra.callbacks in a primary config): what a sweep does when it ends."""

from __future__ import annotations

import logging

from hydra.experimental.callback import Callback

log = logging.getLogger(__name__)


class SweepTables(Callback):
    """After a dynamics-diversity sweep: its Table 4 and figure in the sweep's folder
    (simeval.measures.dynamics_diversity.sweep_tables). The runs' result.json files are the record; a table that cannot
    be drawn is a warning, never a failed sweep."""

    def on_multirun_end(self, config, **kwargs) -> None:
        from simeval.errors import UserError
        from simeval.measures.dynamics_diversity.sweep_tables import write_sweep_tables

        try:
            written = write_sweep_tables(config.hydra.sweep.dir)
        except (UserError, OSError, ValueError, KeyError) as e:
            log.warning("the sweep's table was not drawn (%s: %s); its runs' result.json files are complete: "
                        "python src/report.py report=table4_heldout report.runs_dir=%s report.out=... report.figure=... "
                        "rebuilds it (report=table4 for protocol=paper runs)",
                        type(e).__name__, e, config.hydra.sweep.dir)
            return
        for path in written:
            log.info("sweep table: %s", path)
        if written:
            print(f"sweep table and figure: {', '.join(str(p) for p in written)}")
