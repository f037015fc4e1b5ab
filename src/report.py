"""The report door: rebuild a paper table, figure or the HTML report from files on disk (no rerun).
    python src/report.py report=table3|figure4|table4|table4_heldout|table5|html|all [overwrite=true]
See conf/report.yaml and conf/report/; the builders are simeval.report.rebuild (callable without Hydra)."""

import logging

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import UserError

log = logging.getLogger("report")


@hydra.main(version_base="1.3", config_path="../conf", config_name="report")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.report.rebuild import rebuild, rebuild_all

    spec = OmegaConf.to_container(cfg.report, resolve=True)
    if spec.get("kind") == "all":  # one line per step; a failed step does not stop the others, but sets the status
        failed = rebuild_all(spec, overwrite=cfg.overwrite, made_under=cfg.paths.root)
        if failed:
            raise UserError(f"report=all: {len(failed)} of its steps not written ({', '.join(failed)}); each step's "
                            "line above says why")
        return
    done = rebuild(spec, overwrite=cfg.overwrite)
    print(done.markdown)
    for note in done.notes:
        print(f"note: {note}")
    log.info("wrote %s", ", ".join(map(str, done.written)))


if __name__ == "__main__":
    launch(main)
