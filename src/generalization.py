"""Paper Table 5: a Diffusion Policy trained on a task group, rolled out on varied and held-out tasks. See
conf/generalization.yaml."""

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch, require_whole_keys
from simeval.errors import UserError, require_folder

log = logging.getLogger("generalization")
VERSION = "1.0"


@hydra.main(version_base="1.3", config_path="../conf", config_name="generalization")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    import torch

    from simeval.models.device import resolve_device
    from simeval.models.policy import evaluate as ev
    from simeval.models.policy.experiment import resolve_action_space, run_splits
    from simeval.models.policy.random_baseline import RandomActions
    from simeval.results import RunFolder
    from simeval.sim.spec import SUITES_DIR
    from simeval.sim.splits import group_and_heldout, split_tasks

    require_whole_keys(cfg, {"episodes_per_task": 1, "val_episodes_per_task": 0, "seed": 0, "eval.seeds": 1,
                             "eval.seed_offset": 0, "torch_threads": 1, "eval.max_steps": 1},
                       optional=("torch_threads", "eval.max_steps"))
    if cfg.torch_threads:
        torch.set_num_threads(cfg.torch_threads)
    device = resolve_device(cfg.device)  # a bad value or a missing GPU stops here, before any data is read
    if not cfg.pipeline.get("suite"):
        raise UserError(f"pipeline={cfg.pipeline.name} has no simeval suite yet (pipeline.suite is null)")
    def names(value):  # `key=a` is a string: one name, not its characters
        return None if value is None else [value] if isinstance(value, str) else list(value)

    specs, heldout = group_and_heldout(SUITES_DIR / cfg.pipeline.suite, cfg.task_group, cfg.tasks,
                                       names(cfg.heldout_tasks))
    group = [s.name for s in specs]
    trained = [t for t in group if t not in heldout]
    model = OmegaConf.to_container(cfg.policy.model, resolve=True)
    chance = cfg.policy.name == "random"  # the chance baseline: uniform random actions, nothing trained
    override = OmegaConf.to_container(cfg.eval.variation, resolve=True) if cfg.eval.variation else None
    plan = {split: [(s.name, v) for s, v in split_tasks(specs, split, heldout, eval_override=override)]
            for split in names(cfg.eval.splits)}  # split names and variation keys are checked here, before training
    for split in [s for s, pairs in plan.items() if not pairs]:
        log.info("split %s: nothing to roll out (%s), skipped", split, "no held-out task" if split == "heldout"
                 else "no task of the group has an eval variation" if split == "eval" else "no trained task")
    plan = {split: pairs for split, pairs in plan.items() if pairs}
    require_folder("checkpoint_dir", cfg.checkpoint_dir)
    run = RunFolder.of(cfg)
    with run.logger() as logger:
        if chance:
            policy = RandomActions(resolve_action_space(model["action_space"], specs), model["cameras"],
                                   model["image_size"])
            ckpt_dir, summary, values = f"{cfg.checkpoint_dir}/random", {"steps": 0}, {"training": None}
            settings_id = {"model": {**model, "action_space": policy.cfg.action_space}}
        else:
            policy, ckpt_dir, summary, values, settings_id = _train(cfg, model, specs, trained, logger, device,
                                                                    run.config)
        seeds = range(cfg.eval.seed_offset, cfg.eval.seed_offset + cfg.eval.seeds)
        rows = run_splits(policy, plan, seeds, cfg.eval.max_steps, f"{ckpt_dir}/rollouts.json", summary["steps"],
                          progress=bool(cfg.progress))
        values.update(tasks=rows, splits=ev.summarize(rows))
        if cfg.eval.videos and rows and not chance:
            values["videos"] = ev.best_and_worst_videos(policy, rows, seeds[0], cfg.eval.max_steps,
                                                        cfg.eval.video_camera, run.output_dir)
            for which, video in values["videos"].items():
                _, split, task = Path(video).stem.split("_", 2)  # videos/<which>_<split>_<task>.mp4
                logger.log_video(f"rollout/{which}", video, caption=(
                    f"{which} task of the {split} split: {task} (seed {seeds[0]}, camera {cfg.eval.video_camera})"))
        identity = {"pipeline": cfg.pipeline.name, "task_group": cfg.task_group, "tasks": group, "policy": cfg.policy.name,
                    "heldout_tasks": heldout, "episodes_per_task": cfg.episodes_per_task,
                    "variations": {t: v for t, v in plan.get("eval", [])},
                    "eval_seeds": cfg.eval.seeds, "settings": settings_id}
        path = run.write(metric="generalization", version=VERSION, values=values, seed=cfg.seed, identity=identity)
        logger.log_metrics({f"{s}/success": v["success"]["rate"] for s, v in values["splits"].items()})
    for s, v in values["splits"].items():
        sr = v["success"]
        log.info("%-10s success %d/%d = %.2f [%.2f, %.2f]  progress %.2f", s, sr["k"], sr["n"], sr["rate"],
                 *sr["ci"], v["mean_progress"])
    log.info("wrote %s", path)


def _train(cfg, model: dict, specs, trained: list[str], logger, device, config: dict):
    """The policy trained (or resumed, or reused) on the trained tasks' episodes, with the sampler check:
    (policy, checkpoint folder, training summary, values so far, the settings that identify it)."""
    from simeval.episodes.store import EpisodeStore
    from simeval.models.diffusion_policy import DiffusionPolicy, PolicyConfig, TrainSettings, train_policy
    from simeval.models.policy import evaluate as ev
    from simeval.models.policy.data import PolicyDataset
    from simeval.models.policy.experiment import checkpoint_key, episodes_for, resolve_action_space

    pcfg = PolicyConfig.from_mapping({**model, "action_space": resolve_action_space(model["action_space"], specs)})
    settings = TrainSettings(**OmegaConf.to_container(cfg.policy.train, resolve=True), seed=cfg.seed)
    train_eps, val_eps, metas = episodes_for(EpisodeStore(cfg.store), cfg.pipeline.name, trained,
                                             cfg.episodes_per_task, cfg.val_episodes_per_task, pcfg.cameras)
    data = PolicyDataset(train_eps, pcfg.action_space, pcfg.cameras, pcfg.image_size, pcfg.horizon, pcfg.n_obs_steps)
    ckpt_dir = f"{cfg.checkpoint_dir}/{checkpoint_key(metas, vars(pcfg), vars(settings), cfg.seed)}"
    fresh = DiffusionPolicy(pcfg, data.state_dim, data.action_dim, data.stats(), seed=cfg.seed)
    policy, summary = train_policy(fresh, data, settings, ckpt_dir, logger.log_metrics, extra={"config": config},
                                   progress=bool(cfg.progress), device=device)
    values = {"training": {**summary, "checkpoint": f"{ckpt_dir}/last.ckpt", "trained_tasks": trained,
                           "windows": len(data)}}
    if cfg.eval.sampler_check and val_eps:
        val = PolicyDataset(val_eps, pcfg.action_space, pcfg.cameras, pcfg.image_size, pcfg.horizon, pcfg.n_obs_steps)
        values["sampler_check"] = ev.sampler_action_error(policy, val, {
            "ddpm": ("ddpm", pcfg.num_train_timesteps), "ddim": ("ddim", pcfg.num_inference_steps)})
    return policy, ckpt_dir, summary, values, {"model": vars(pcfg), "train": vars(settings)}


if __name__ == "__main__":
    launch(main)
