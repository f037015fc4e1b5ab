"""Single-task quality by VLM/LLM judges (paper Sec. 3.3 / 4.1). See conf/quality.yaml and
simeval.measures.quality.run.run_quality.

Exit status: 0 when at least one task was scored; 1 when the run ran but every task failed (no valid score: status
"failed" in result.json, one line on stderr); 2 for a mistake in the config or the inputs (one line on stderr)."""

import json
import logging

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import QualityConfig, check_values
from simeval.errors import require_folder

log = logging.getLogger("quality")


@hydra.main(version_base="1.3", config_path="../conf", config_name="quality")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from simeval.measures.quality.run import Scoring, model_judge, run_quality
    from simeval.results import RunFolder

    check_values(cfg, QualityConfig)  # for every judge, oracle included
    require_folder("cache_dir", cfg.cache_dir)
    run = RunFolder.of(cfg)
    judge = "oracle"
    if cfg.judge.kind != "oracle":
        captioner = instantiate(cfg.captioner.provider) if cfg.captioner.kind != "none" else None
        judge = model_judge(instantiate(cfg.judge.provider), captioner, judge=run.config["judge"],
                            captioner_settings=run.config["captioner"], prompts=run.config["prompts"],
                            cache_dir=cfg.cache_dir, budget_usd=cfg.budget_usd, repeats=cfg.repeats,
                            max_reasks=cfg.max_reasks)
    meta = dict(config=run.config, choices=run.choices, seed=cfg.seed, overrides=run.overrides, label=cfg.label)
    with run.logger() as logger:
        out = run_quality(run.output_dir, bundles_dir=cfg.bundles_dir, episodes=run.config["episodes"], judge=judge,
                          scoring=Scoring(cfg.metric, cfg.scene_alignment_mode, cfg.n_frames), dry_run=cfg.dry_run,
                          logger=logger, meta=meta)
    if out.plan is not None:  # a dry run: stdout is the plan, as JSON, and nothing else
        print(json.dumps(out.plan, indent=2))
        return
    log.info(out.summary)
    if out.status == "failed":
        raise SystemExit(f"error: {out.error}")  # exit status 1: the run ran and every task failed (module docstring)


if __name__ == "__main__":
    launch(main)
