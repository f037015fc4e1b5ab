"""Rebuild a paper table, figure or the HTML report from files on disk (no rerun). See conf/report.yaml and
conf/report/."""

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import UserError

log = logging.getLogger("report")


@hydra.main(version_base="1.3", config_path="../conf", config_name="report")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.report.build import build_text_diversity_report
    from simeval.report.quality_figure import build_quality_figure
    from simeval.results import read_results

    spec = OmegaConf.to_container(cfg.report, resolve=True)
    if spec.get("kind") != "html" and read_results(spec["runs_dir"], spec.get("metric")):
        # with runs to report only (without, the builder's own error says what to run); the HTML report writes into
        # the runs' folder, never over a committed result
        from simeval.report.tables import outputs_named, refuse_committed

        refuse_committed(outputs_named(spec["out_dir"], spec["id"]), bool(cfg.overwrite), "overwrite=true")
    if spec.get("kind") == "html":
        from simeval.report.html import build_html_report

        page = build_html_report(spec["runs_dir"], spec.get("out_dir"), tables_dir=spec.get("tables_dir"),
                                 figures_dir=spec.get("figures_dir"), title=spec.get("title", "simeval report"))
        print(f"HTML report: {page} (open it in a browser; the folder is self-contained)")
        return
    if spec["metric"] == "quality":
        written = build_quality_figure(spec["runs_dir"], spec["out_dir"], id=spec["id"])
        print(Path(written["table"][1]).read_text())
        for kind, paths in written.items():
            log.info("%s: %s", kind, ", ".join(map(str, paths)))
        return
    if spec["metric"] != "text_diversity":
        raise UserError(f"report.metric={spec['metric']!r}: expected text_diversity or quality")
    written = build_text_diversity_report(
        spec["runs_dir"], spec["out_dir"], id=spec["id"], rows=spec["rows"], columns=spec["columns"],
        caption=spec.get("caption", ""), statistic=spec.get("statistic", "div"), digits=spec.get("digits", 2),
    )
    print(Path(written["main"][1]).read_text())
    for kind, paths in written.items():
        log.info("%s: %s", kind, ", ".join(map(str, paths)))


if __name__ == "__main__":
    launch(main)
