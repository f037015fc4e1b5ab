"""Judge-human agreement: Pearson, MAE, r/MAE, Spearman, Kendall with bootstrap CIs; Figure 3. See conf/agreement.yaml."""

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import AgreementConfig, check_values

log = logging.getLogger("agreement")


@hydra.main(version_base="1.3", config_path="../conf", config_name="agreement")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.measures.agreement.figure3 import plot_figure3
    from simeval.measures.agreement.run import agreement_rows, format_rows, load_score_tables
    from simeval.errors import UserError
    from simeval.measures.agreement.metric import METRIC_VERSION
    from simeval.writing.figures import check_figure_formats
    from simeval.writing.tables import write_table
    from simeval.results import RunFolder

    check_values(cfg, AgreementConfig)
    check_figure_formats("figure_formats", list(cfg.figure_formats))  # before the tables are written
    if not cfg.scores_path:
        raise UserError("scores_path is not set: scores_path=FILE (or env SIMEVAL_HUMAN_SCORES)")
    run = RunFolder.of(cfg)
    out = Path(run.output_dir)
    tables = load_score_tables(cfg.scores_path, human=cfg.human_column)  # validated: a UserError names file/row/column
    rows = agreement_rows(tables, cfg.human_column, n_boot=cfg.n_boot, seed=cfg.seed)
    header, body = format_rows(rows)
    write_table(out / "agreement", header, body, caption="Agreement of judges with human scores (95% bootstrap CIs).")
    figures = plot_figure3(rows, out / "figure3", tuple(cfg.figure_formats))
    with run.logger() as logger:
        run.write(metric="agreement", version=METRIC_VERSION, values=rows, seed=cfg.seed,
                  figures=[f.name for f in figures])  # relative to the run folder
        logger.log_metrics({f"{r['table']}/{r['pipeline']}/{r['judge']}": {"r_over_mae": r["r_over_mae"],
                                                                          "pearson": r["pearson"], "mae": r["mae"]}
                            for r in rows})
    print((out / "agreement.md").read_text())
    log.info("wrote %s and %s", out / "agreement.md", ", ".join(map(str, figures)))


if __name__ == "__main__":
    launch(main)
