"""Dynamics-based trajectory diversity: a world model per (group, episodes) (paper Table 4). See conf/diversity.yaml."""

import logging
import shlex

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import DiversityConfig, check_values
from simeval.errors import require_folder

log = logging.getLogger("diversity")


@hydra.main(version_base="1.3", config_path="../conf", config_name="diversity")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    import torch
    from hydra.core.hydra_config import HydraConfig

    from simeval.runtime.captured import training_device
    from simeval.measures.dynamics_diversity.run import (VERSION, DiversityRun, Execution, episode_source, headline,
                                                         refuse_heldout_settings_given, tasks_not_stored)
    from simeval.pipelines.registry import own_code_args
    from simeval.results import RunFolder

    check_values(cfg, DiversityConfig)
    if cfg.checkpoint_dir is not None:  # null: no checkpoints (no resume)
        require_folder("checkpoint_dir", cfg.checkpoint_dir)
    run = RunFolder.of(cfg)
    measure = DiversityRun.from_config(run.config)
    refuse_heldout_settings_given(list(HydraConfig.get().overrides.task), measure.protocol["name"])
    torch.set_num_threads(cfg.threads)
    device = training_device(cfg.device, cfg.capture)  # a bad value or a missing GPU stops here, before any data
    # episodes_needed checks every protocol.* value first, so a bad one stops here, before the store is read
    # a plugin pipeline's config folder: the collect command it suggests needs it too
    searchpath = "".join(f" {shlex.quote(o)}" for o in HydraConfig.get().overrides.hydra
                         if o.startswith("hydra.searchpath="))
    camera = cfg.camera if measure.pixels is not False else None  # states only: episodes without frames serve
    source, how_to_get_more = episode_source(cfg.store, cfg.pipeline.name, cfg.task_group, camera,
                                             suite=cfg.pipeline.get("suite"), own_code=own_code_args(cfg.pipeline),
                                             episodes_needed=measure.episodes_needed,
                                             debug_overlay=HydraConfig.get().runtime.choices.get("debug") or "none",
                                             collect_extra=searchpath)
    read = sorted({info.task for info in source.infos})
    missing = tasks_not_stored(read, cfg.task_group, cfg.pipeline.get("suite"))
    if missing:
        log.warning("%s/%s: the store holds %d of the group's %d tasks (%s); the reading is of those only (not "
                    "read: %s)", cfg.pipeline.name, cfg.task_group, len(read), len(read) + len(missing),
                    ", ".join(read), ", ".join(missing))
    with run.logger() as logger:
        execution = Execution(checkpoint_dir=cfg.checkpoint_dir, device=device, compile=cfg.compile,
                              capture=cfg.capture, progress=bool(cfg.progress), how_to_get_more=how_to_get_more)
        values = measure.fit(source, execution, logger, videos=int(cfg.videos), video_dir=f"{run.output_dir}/videos")
        path = run.write(metric="dynamics_diversity", version=VERSION, values=values, seed=int(cfg.seed),
                         identity=measure.identity(source), overrides=run.overrides)
        logger.log_metrics(headline(values))
    log.info("%s; wrote %s", measure.describe(device, values), path)


if __name__ == "__main__":
    launch(main)
