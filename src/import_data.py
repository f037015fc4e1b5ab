"""Import demonstrations (Ravens/CLIPort, the paper authors' GenSim/BBSEA/RoboGen files, LeRobotDataset folders,
robomimic HDF5 files) into the episode store."""

import inspect
import logging
import re

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import ImportDataConfig, check_values
from simeval.errors import UserError

log = logging.getLogger("import_data")


@hydra.main(version_base="1.3", config_path="../conf", config_name="import_data")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.pipelines.importers import IMPORTERS, image_size_option, import_into_store
    from simeval.episodes.store import EpisodeStore
    from simeval.results import RunFolder

    check_values(cfg, ImportDataConfig)
    if cfg.format not in IMPORTERS:
        raise UserError(f"format={cfg.format!r}: expected one of {', '.join(IMPORTERS)}")
    if not cfg.src:
        raise UserError("src is not set: src=/path/to/demonstrations")
    if cfg.name is not None and not re.fullmatch(r"[A-Za-z0-9_-]+", str(cfg.name)):
        raise UserError(f"name={cfg.name}: letters, digits, '-' and '_' only (it names the store's folder)")
    importer = IMPORTERS[cfg.format]
    size = OmegaConf.to_container(cfg.image_size) if OmegaConf.is_config(cfg.image_size) else cfg.image_size
    options = {"image_size": image_size_option(size, "image_size"),
               "groups": _mapping(cfg.groups), "descriptions": _mapping(cfg.descriptions), "name": cfg.name,
               "filter_key": cfg.filter_key}
    accepted = inspect.signature(importer).parameters  # each format takes the options it has a use for
    summary = import_into_store(importer, cfg.src, EpisodeStore(cfg.store), overwrite=cfg.overwrite,
                                **{k: v for k, v in options.items() if k in accepted})
    RunFolder.of(cfg).write(metric="import", version="1.0", values=summary)
    log.info("%s: %d written, %d already in %s (pipeline %s)", cfg.format, summary["written"], summary["skipped"],
             cfg.store, ", ".join(summary["pipelines"]) or "none")


def _mapping(value) -> dict:
    return {} if value is None else OmegaConf.to_container(value)


if __name__ == "__main__":
    launch(main)
