"""Single-task quality by VLM/LLM judges (paper Sec. 3.3 / 4.1). See conf/quality.yaml."""

import dataclasses
import json
import logging
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parent))
from simeval.cli import allow_multirun_anywhere  # noqa: E402

log = logging.getLogger("quality")
CONF = Path(__file__).resolve().parent.parent / "conf"


@hydra.main(version_base="1.3", config_path="../conf", config_name="quality")
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from simeval.judges.cache import JudgeCache
    from simeval.judges.ledger import Ledger, Prices
    from simeval.judges.prompts import load_template
    from simeval.judges.runner import JudgeSettings
    from simeval.judges.ledger import BudgetExceeded
    from simeval.judges.runner import ReplayMiss
    from simeval.quality import evaluate_quality, judge_reliability, load_bundles, oracle_completion, summarize
    from simeval.results import atomic_write_text, hydra_run_info, write_result

    run, config = hydra_run_info(), OmegaConf.to_container(cfg, resolve=True)
    out_dir = Path(run["output_dir"])
    bundles_dir = cfg.bundles_dir
    if cfg.episodes.store:  # judge episodes of the store: export them as bundles into the run folder first
        from simeval.episodes.bundles import export_bundles

        bundles_dir = out_dir / "bundles"
        export_bundles(cfg.episodes.store, bundles_dir, **{k: v for k, v in cfg.episodes.items() if k != "store"})
    if not bundles_dir:
        raise ValueError("set bundles_dir=DIR (or env SIMEVAL_BUNDLES), or episodes.store=DIR (an episode store)")
    bundles, errors = load_bundles(bundles_dir)
    meta = dict(metric="quality", version="1.0", config=config, choices=run["choices"], seed=cfg.seed,
                overrides=run["overrides"], judge=cfg.judge.kind, label=cfg.label,
                tasks={b.name: {"pipeline": b.pipeline} for b in bundles})
    if cfg.judge.kind == "oracle":
        values = {"task_completion": oracle_completion(bundles)}
        write_result(out_dir, values=values, errors=errors, **meta)
        return
    templates = {k: load_template(v, CONF) for k, v in cfg.prompts.items()}
    cache = JudgeCache(Path(cfg.cache_dir) / "judge_calls.sqlite")
    ledger = Ledger(Prices(**cfg.judge.prices), cfg.budget_usd)
    settings = JudgeSettings(cfg.repeats, cfg.max_reasks, cfg.judge.concurrency, cfg.judge.rate_limit_per_min,
                             cfg.judge.replay)
    captioner, cap_settings = None, None
    if cfg.scene_alignment_mode == "caption" and cfg.captioner.kind != "none":
        captioner = instantiate(cfg.captioner.provider)
        cap_settings = JudgeSettings(1, cfg.max_reasks, cfg.captioner.concurrency,
                                     cfg.captioner.rate_limit_per_min, cfg.judge.replay)
    try:
        out = evaluate_quality(bundles, metric=cfg.metric, mode=cfg.scene_alignment_mode,
                               provider=instantiate(cfg.judge.provider), templates=templates, cache=cache,
                               ledger=ledger, settings=settings, captioner=captioner, caption_settings=cap_settings,
                               n_frames=cfg.n_frames, dry=cfg.dry_run)
    except (BudgetExceeded, ReplayMiss) as e:  # keep what finished (it is cached too), then stop loudly
        done = getattr(e, "partial", [])
        write_result(out_dir, values=summarize(done), errors=errors, cost=ledger.totals(), status="stopped",
                     stopped=str(e), **meta)
        raise
    errors.update(out["errors"])
    if cfg.dry_run:
        print(json.dumps(out["dry_run"], indent=2))
        return
    lines = [json.dumps(dataclasses.asdict(r) | {"valid": r.valid}) for r in out["records"]]
    atomic_write_text(out_dir / "scores.jsonl", "\n".join(lines) + "\n")
    with instantiate(cfg.logger, _partial_=True)(run_dir=str(out_dir), run_config=config) as logger:
        write_result(out_dir, values=out["summary"], errors=errors, cost=ledger.totals(),
                     reliability=judge_reliability(out["records"]), **meta)
        logger.log_metrics({"cost": ledger.totals()})
    log.info("judged %d tasks (%d failed: %s); cost %s", len(bundles), len(errors), sorted(errors), ledger.totals())


if __name__ == "__main__":
    allow_multirun_anywhere()
    main()
