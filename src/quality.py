"""Single-task quality by VLM/LLM judges (paper Sec. 3.3 / 4.1). See conf/quality.yaml."""

import json
import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch

log = logging.getLogger("quality")
CONF = Path(__file__).resolve().parent.parent / "conf"


@hydra.main(version_base="1.3", config_path="../conf", config_name="quality")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from simeval import quality as q
    from simeval.judges.cache import JudgeCache
    from simeval.judges.ledger import BudgetExceeded, Ledger, Prices
    from simeval.judges.prompts import load_template
    from simeval.judges.runner import JudgeSettings, ReplayMiss
    from simeval.results import hydra_run_info, write_result

    run, config = hydra_run_info(), OmegaConf.to_container(cfg, resolve=True)
    out_dir = Path(run["output_dir"])
    bundles, errors = q.load_bundles(q.resolve_bundles_dir(cfg.bundles_dir, config["episodes"], out_dir))
    meta = dict(metric="quality", version="1.0", config=config, choices=run["choices"], seed=cfg.seed,
                overrides=run["overrides"], judge=cfg.judge.kind, label=cfg.label,
                tasks={b.name: {"pipeline": b.pipeline} for b in bundles})
    if cfg.judge.kind == "oracle":
        scores = q.oracle_completion(bundles)
        errors.update({b.name: "no ground truth (success or progress) in task.yaml" for b in bundles
                       if b.name not in scores})
        write_result(out_dir, values={"task_completion": scores}, errors=errors, **meta)
        return
    ledger = Ledger(Prices(**cfg.judge.prices), cfg.budget_usd)
    settings = JudgeSettings(cfg.repeats, cfg.max_reasks, cfg.judge.concurrency, cfg.judge.rate_limit_per_min,
                             cfg.judge.replay)
    captioner, caption_settings = None, None
    if cfg.captioner.kind != "none":  # the captioner captions each view once; every judge repeat reuses it
        captioner = instantiate(cfg.captioner.provider)
        caption_settings = JudgeSettings(1, cfg.max_reasks, cfg.captioner.concurrency,
                                         cfg.captioner.rate_limit_per_min, cfg.judge.replay)
    try:
        out = q.evaluate_quality(
            bundles, metric=cfg.metric, mode=cfg.scene_alignment_mode, provider=instantiate(cfg.judge.provider),
            templates={k: load_template(v, CONF) for k, v in cfg.prompts.items()}, ledger=ledger,
            cache=JudgeCache(Path(cfg.cache_dir) / "judge_calls.sqlite"), settings=settings, captioner=captioner,
            caption_settings=caption_settings, n_frames=cfg.n_frames, dry=cfg.dry_run)
    except (BudgetExceeded, ReplayMiss) as e:  # keep what finished (it is cached too), then stop loudly
        write_result(out_dir, values=q.summarize(getattr(e, "partial", [])), errors=errors, cost=ledger.totals(),
                     status="stopped", stopped=str(e), **meta)
        raise
    errors.update(out["errors"])
    if cfg.dry_run:
        print(json.dumps(out["dry_run"], indent=2))
        return
    q.write_scores(out_dir / "scores.jsonl", out["records"])
    with instantiate(cfg.logger, _partial_=True)(run_dir=str(out_dir), run_config=config) as logger:
        write_result(out_dir, values=out["summary"], errors=errors, cost=ledger.totals(),
                     reliability=q.judge_reliability(out["records"]), **meta)
        logger.log_metrics({"cost": ledger.totals()})
    log.info("judged %d tasks (%d failed: %s); cost %s", len(bundles), len(errors), sorted(errors), ledger.totals())


if __name__ == "__main__":
    launch(main)
