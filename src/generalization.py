"""Paper Table 5: a Diffusion Policy trained on a task group, rolled out on varied and held-out tasks. See
conf/generalization.yaml."""

import logging

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import GeneralizationConfig, check_values
from simeval.errors import require_folder

log = logging.getLogger("generalization")


@hydra.main(version_base="1.3", config_path="../conf", config_name="generalization")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    import torch

    from simeval.runtime.device import resolve_device
    from simeval.measures.generalization.run import (RESULT_VERSION, GeneralizationRun, PolicyTraining,
                                                     log_splits, refuse_replaced_chance_baseline,
                                                     run_generalization)
    from simeval.pipelines.registry import pipeline_from_config
    from simeval.results import RunFolder

    check_values(cfg, GeneralizationConfig)
    torch.set_num_threads(cfg.torch_threads or torch.get_num_threads())  # null: torch's own default
    device = resolve_device(cfg.device)  # a bad value or a missing GPU stops here, before any data is read
    require_folder("checkpoint_dir", cfg.checkpoint_dir)
    run = RunFolder.of(cfg)
    refuse_replaced_chance_baseline(run.choices.get("policy"), cfg.policy.name)
    conf = run.config
    pipeline = pipeline_from_config(conf["pipeline"])  # its suite, or its own code (GenSim's from a checkout)
    with run.logger() as logger:
        training = PolicyTraining(conf["policy"]["model"], conf["policy"].get("train"), cfg.seed, cfg.store,
                                  cfg.episodes_per_task, cfg.val_episodes_per_task, cfg.demonstrations)
        experiment = GeneralizationRun(pipeline, cfg.task_group, conf["tasks"], conf["heldout_tasks"], cfg.policy.name,
                                       training, conf["eval"])
        values, identity = run_generalization(experiment, checkpoint_dir=cfg.checkpoint_dir, run_dir=run.output_dir,
                                              logger=logger, device=device, progress=bool(cfg.progress), config=conf)
        path = run.write(metric="generalization", version=RESULT_VERSION, values=values, seed=cfg.seed, identity=identity)
        logger.log_metrics({f"{s}/success": v["success"]["rate"] for s, v in values["splits"].items()
                            if v["success"]["n"]})  # none rolled out: every scene was the train split's
    log_splits(values)
    log.info("policy %s; wrote %s", cfg.policy.name, path)


if __name__ == "__main__":
    launch(main)
