"""Collect oracle episodes of a simeval suite into the episode store. See conf/collect.yaml.

Exit status: 0 done; 2 a mistake in the command or config (one line on stderr, nothing collected); 1 a worker
process died (e.g. the out-of-memory killer): one line naming its episode, the finished episodes are kept and
the same command resumes; 130 / 143 stopped by Ctrl-C / SIGTERM (finished episodes kept)."""

import logging
import sys

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch, require_whole_keys
from simeval.errors import UserError

log = logging.getLogger("collect")


@hydra.main(version_base="1.3", config_path="../conf", config_name="collect")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.collect import WorkerDied, collect, plan_suite
    from simeval.episodes.store import EpisodeStore
    from simeval.results import RunFolder
    from simeval.sim.rollout import RecordSettings
    from simeval.sim.spec import SUITES_DIR

    require_whole_keys(cfg, {"episodes": 1, "seed_offset": 0})
    if cfg.pipeline.get("native"):  # the pipeline's own code (GenSim's, from its checkout)
        return collect_native(cfg)
    if not cfg.pipeline.get("suite"):
        raise UserError(f"pipeline={cfg.pipeline.name} has no simeval suite yet (pipeline.suite is null)")
    run = RunFolder.of(cfg)
    specs, variation, per_task = plan_suite(SUITES_DIR / cfg.pipeline.suite, run.config["tasks"], cfg.task_group,
                                            cfg.variation.split, run.config["variation"]["knobs"])
    seeds = range(cfg.seed_offset, cfg.seed_offset + cfg.episodes)
    try:
        summary = collect(specs, seeds, EpisodeStore(cfg.store), RecordSettings(**run.config["record"]),
                          pipeline=cfg.pipeline.name, workers=cfg.workers, variation=variation,
                          task_variations=per_task)
    except KeyboardInterrupt:  # the library has logged what was kept; no traceback for a Ctrl-C
        raise SystemExit(130) from None
    except WorkerDied as e:  # not the user's mistake (exit 2): a resumable failure of the machine
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(1) from None
    with run.logger() as logger:
        run.write(metric="collect", version="1.0", values=summary)
        logger.log_metrics({"oracle_success": {t: v["rate"] for t, v in summary["tasks"].items()}})
    for task, t in summary["tasks"].items():
        log.info("%-32s %-11s %d/%d oracle successes", task, t["group"], t["success"], t["episodes"])
    log.info("%d new episodes, %d already in %s", len(summary["new"]), summary["skipped"], cfg.store)


def collect_native(cfg: DictConfig) -> None:
    from simeval.pipelines.gensim.native import collect_from_checkout
    from simeval.results import RunFolder

    run = RunFolder.of(cfg)
    try:
        summary = collect_from_checkout(cfg.pipeline.root, run.config["pipeline"]["native"], run.config["tasks"],
                                        cfg.task_group, range(cfg.seed_offset, cfg.seed_offset + cfg.episodes),
                                        cfg.store, run.config["record"], pipeline=cfg.pipeline.name, workers=cfg.workers)
    except KeyboardInterrupt:  # the episodes stored so far are kept; the same command resumes
        raise SystemExit(130) from None
    with run.logger() as logger:
        run.write(metric="collect", version="1.0", values=summary)
        logger.log_metrics({"oracle_success": {t: v["rate"] for t, v in summary["tasks"].items()}})
    for task, t in summary["tasks"].items():
        log.info("%-40s %-11s %d/%d oracle successes%s", task, t["group"], t["success"], t["episodes"],
                 f", {len(t['failed'])} failed (seeds {t['failed']})" if t["failed"] else "")
    log.info("%d new GenSim episodes, %d already in %s, %d failed", len(summary["new"]), summary["skipped"],
             cfg.store, len(summary["failed"]))
    if summary["failed"] and not summary["new"] and not summary["skipped"]:
        first = summary["failed"][0]
        print(f"error: every GenSim episode failed; the first, {first['task']} seed {first['seed']}, raised "
              f"{first['error']}" + (f" at {first['where']}" if first["where"] else "") + " (all of them: the log "
              "and result.json)", file=sys.stderr)
        raise SystemExit(1)


if __name__ == "__main__":
    launch(main)
