"""Dynamics-based trajectory diversity: a world model per (group, episodes) (paper Table 4). See conf/diversity.yaml."""

import logging

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch, require_whole_keys
from simeval.errors import UserError, require_folder

log = logging.getLogger("diversity")


@hydra.main(version_base="1.3", config_path="../conf", config_name="diversity")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    import torch
    from hydra.core.hydra_config import HydraConfig

    from simeval.models.device import resolve_device
    from simeval.models.dynamics_diversity import (DiversityRun, headline, how_to_get_episodes, ranks_of,
                                                   store_source, summary_line)
    from simeval.models.world_model import VERSION
    from simeval.results import RunFolder

    require_whole_keys(cfg, {"episodes": 1, "threads": 1, "seed": 0, "videos": 0, "eval.seed": 0, "eval.context": 1,
                             "eval.batch_size": 1})
    for key in ("compile", "capture"):
        if not isinstance(cfg[key], bool):
            raise UserError(f"{key}={'null' if cfg[key] is None else repr(cfg[key])}: expected true or false")
    if cfg.checkpoint_dir is not None:  # null: no checkpoints (no resume)
        require_folder("checkpoint_dir", cfg.checkpoint_dir)
    run = RunFolder.of(cfg)
    conf = run.config
    measure = DiversityRun(cfg.pipeline.name, cfg.task_group, cfg.camera, int(cfg.episodes), int(cfg.seed),
                           conf["world_model"], conf["protocol"], conf["eval"],
                           ranks_of(conf["eval_episodes"], "eval_episodes"),
                           ranks_of(conf["heldout_episodes"], "heldout_episodes"))
    torch.set_num_threads(cfg.threads)
    device = resolve_device(cfg.device)  # a bad value or a missing GPU stops here, before any data is read
    if cfg.capture and device.type != "cuda":
        from simeval.models.captured import capture_needs_cuda

        raise capture_needs_cuda(f"device={cfg.device} resolves to {device} here")
    _ = measure.configs  # a bad protocol.* value stops here, before the store is read
    needed = max(int(cfg.episodes), (measure.eval_episodes or (0, 40))[1])  # protocol=paper's held-out: optional
    overlay = HydraConfig.get().runtime.choices.get("debug") or "none"  # its recording settings must match the run's
    debug = f" debug={overlay}" if overlay != "none" else ""
    suite, native = cfg.pipeline.get("suite"), bool(cfg.pipeline.get("native"))
    source = store_source(cfg.store, cfg.pipeline.name, cfg.task_group, cfg.camera, suite, needed, debug, native)
    identity = measure.identity(source)
    with run.logger() as logger:
        values = measure.fit(source, checkpoint_dir=cfg.checkpoint_dir, logger=logger, device=device,
                             compile=cfg.compile, capture=cfg.capture, videos=int(cfg.videos),
                             video_dir=f"{run.output_dir}/videos",
                             progress=bool(cfg.progress), how_to_get_more=lambda n: how_to_get_episodes(
                                 cfg.store, cfg.pipeline.name, cfg.task_group, suite, n, debug, native))
        path = run.write(metric="dynamics_diversity", version=VERSION, values=values, seed=int(cfg.seed),
                         identity=identity, overrides=run.overrides)
        logger.log_metrics(headline(values))
    log.info("%s/%s episodes=%d [preset %s, device %s, protocol=%s]: %s", cfg.pipeline.name, cfg.task_group,
             cfg.episodes, measure.world_model["name"], device, measure.protocol["name"], summary_line(values))
    log.info("wrote %s", path)


if __name__ == "__main__":
    launch(main)
