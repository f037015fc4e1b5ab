"""Collect oracle episodes of a pipeline (its simeval suite, or its own code) into the episode store. See
conf/collect.yaml.

Exit status: 0 done; 2 a mistake in the command or config (one line on stderr, nothing collected); 1 a worker
process died (e.g. the out-of-memory killer): one line naming its episode, the finished episodes are kept and
the same command resumes; 130 / 143 stopped by Ctrl-C / SIGTERM (finished episodes kept)."""

import logging
import sys

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import CollectConfig, check_values

log = logging.getLogger("collect")


@hydra.main(version_base="1.3", config_path="../conf", config_name="collect")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.collect import WorkerDied, log_summary
    from simeval.pipelines.registry import pipeline_class
    from simeval.results import RunFolder

    check_values(cfg, CollectConfig)
    collector = pipeline_class(cfg.pipeline, needs="collection")
    run = RunFolder.of(cfg)
    try:
        summary = collector.collect(run.config["pipeline"], tasks=run.config["tasks"], task_group=cfg.task_group,
                                    seeds=range(cfg.seed_offset, cfg.seed_offset + cfg.episodes), store=cfg.store,
                                    record=run.config["record"], variation=run.config["variation"],
                                    workers=cfg.workers)
    except KeyboardInterrupt:  # the library has logged what was kept; no traceback for a Ctrl-C
        raise SystemExit(130) from None
    except WorkerDied as e:  # not the user's mistake (exit 2): a resumable failure of the machine
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(1) from None
    with run.logger() as logger:
        path = run.write(metric="collect", version="1.0", values=summary)
        logger.log_metrics({"oracle_success": {t: v["rate"] for t, v in summary["tasks"].items()}})
    log.info("wrote %s", path)
    failure = log_summary(summary, cfg.store)
    if failure is not None:
        print(f"error: {failure}", file=sys.stderr)
        raise SystemExit(1)


if __name__ == "__main__":
    launch(main)
