"""Dynamics-based trajectory diversity: a world model per (group, episodes) (paper Table 4). See conf/diversity.yaml."""

import logging

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch, require_whole_keys
from simeval.errors import UserError, require_folder

log = logging.getLogger("diversity")


def _ranks(value, key: str) -> tuple[int, int] | None:
    if value is None:
        return None
    bounds = list(value) if isinstance(value, (list, tuple)) or OmegaConf.is_list(value) else [value]
    if len(bounds) != 2 or not all(isinstance(b, int) and not isinstance(b, bool) for b in bounds):
        raise UserError(f"{key}={value!r}: expected [first, last] episode numbers, e.g. {key}=[1,40]")
    lo, hi = bounds
    if not 1 <= lo <= hi:
        raise UserError(f"{key}={list(value)}: expected [first, last] episode numbers, 1 <= first <= last")
    return lo - 1, hi


@hydra.main(version_base="1.3", config_path="../conf", config_name="diversity")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    import torch
    from hydra.core.hydra_config import HydraConfig

    from simeval.episodes.dataset import WindowSpec
    from simeval.models.device import resolve_device
    from simeval.models.dynamics_diversity import (VIDEO_FPS, check_eval_context, check_heldout_settings,
                                                   data_fingerprint, fit_and_evaluate, headline, how_to_get_episodes,
                                                   store_source, summary_line)
    from simeval.models.training import TrainConfig
    from simeval.models.world_model import VERSION, WorldModelConfig
    from simeval.results import RunFolder

    require_whole_keys(cfg, {"episodes": 1, "threads": 1, "seed": 0, "videos": 0, "eval.seed": 0, "eval.context": 1,
                             "eval.batch_size": 1})
    if not isinstance(cfg.compile, bool):
        raise UserError(f"compile={'null' if cfg.compile is None else repr(cfg.compile)}: expected true or false")
    if cfg.checkpoint_dir is not None:  # null: no checkpoints (no resume)
        require_folder("checkpoint_dir", cfg.checkpoint_dir)
    eval_ranks = _ranks(cfg.eval_episodes, "eval_episodes")
    heldout_ranks = _ranks(cfg.heldout_episodes, "heldout_episodes")
    torch.set_num_threads(cfg.threads)
    device = resolve_device(cfg.device)  # a bad value or a missing GPU stops here, before any data is read
    wm = OmegaConf.to_container(cfg.world_model, resolve=True)
    model_cfg = WorldModelConfig.from_dict(wm["model"])
    train_cfg = TrainConfig.from_dict({**wm["train"], "seed": int(cfg.seed)})
    window = WindowSpec(**wm["window"])
    check_eval_context(int(cfg.eval.context), window)
    protocol = cfg.protocol.name
    # protocol=paper leaves these null (it has no robot masks in its score or loss)
    mask_margin = cfg.protocol.get("mask_margin", 0) if protocol == "heldout" else 0
    exclude_robot = cfg.protocol.get("exclude_robot_from_loss", False) if protocol == "heldout" else False
    if protocol == "heldout":  # a bad protocol.* value stops here, before the store is read
        check_heldout_settings(cfg.protocol.steps, cfg.protocol.horizon, cfg.protocol.lr, mask_margin,
                               int(cfg.eval.context), exclude_robot)
    needed = max(int(cfg.episodes), (eval_ranks or (0, 40))[1])  # protocol=paper's held-out episodes are optional
    overlay = HydraConfig.get().runtime.choices.get("debug") or "none"  # its recording settings must match the run's
    debug = f" debug={overlay}" if overlay != "none" else ""
    source = store_source(cfg.store, cfg.pipeline.name, cfg.task_group, cfg.camera, cfg.pipeline.get("suite"), needed,
                          debug)
    run = RunFolder.of(cfg)
    config = run.config
    identity = dict(pipeline=cfg.pipeline.name, task_group=cfg.task_group, episodes=int(cfg.episodes),
                    preset=wm["name"], camera=cfg.camera, episodes_sha=data_fingerprint(source.infos),
                    settings={"world_model": wm, "eval": config["eval"], "eval_episodes": config["eval_episodes"]})
    if protocol != "paper":  # the paper protocol's identity is what it was, so earlier runs still match theirs
        identity.update(protocol=protocol, steps=cfg.protocol.steps)
        identity["settings"]["protocol"] = config["protocol"]
    with run.logger() as logger:
        values = fit_and_evaluate(
            source, episodes_per_task=int(cfg.episodes), model_cfg=model_cfg, train_cfg=train_cfg, window=window,
            eval_episodes=eval_ranks, protocol=protocol, steps=cfg.protocol.steps, horizon=cfg.protocol.horizon,
            lr=cfg.protocol.lr, mask_margin=mask_margin, exclude_robot_from_loss=exclude_robot,
            heldout_episodes=heldout_ranks if protocol == "paper" else None, eval_seed=int(cfg.eval.seed),
            eval_context=int(cfg.eval.context), eval_batch_size=int(cfg.eval.batch_size),
            checkpoint_dir=cfg.checkpoint_dir, log_metrics=logger.log_metrics, progress=bool(cfg.progress),
            videos=int(cfg.videos), video_dir=f"{run.output_dir}/videos", device=device, compile=cfg.compile,
            how_to_get_more=lambda n: how_to_get_episodes(cfg.store, cfg.pipeline.name, cfg.task_group,
                                                          cfg.pipeline.get("suite"), n, debug))
        for task, video in values["videos"].items():
            logger.log_video(f"open_loop/{task}", video, fps=VIDEO_FPS, caption=(
                f"{task}: ground truth | reconstruction | open loop after {int(cfg.eval.context)} observed "
                "frames (red separators: imagined)"))
        path = run.write(metric="dynamics_diversity", version=VERSION, values=values, seed=int(cfg.seed),
                         identity=identity, overrides=run.overrides)
        logger.log_metrics(headline(values))
    log.info("%s/%s episodes=%d [preset %s, device %s, protocol=%s]: %s", cfg.pipeline.name, cfg.task_group,
             cfg.episodes, wm["name"], device, protocol, summary_line(values))
    log.info("wrote %s", path)


if __name__ == "__main__":
    launch(main)
