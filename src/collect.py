"""Collect oracle episodes of a simeval suite into the episode store. See conf/collect.yaml.

Exit status: 0 done; 2 a mistake in the command or config (one line on stderr, nothing collected); 1 a worker
process died (e.g. the out-of-memory killer): one line naming its episode, the finished episodes are kept and
the same command resumes; 130 / 143 stopped by Ctrl-C / SIGTERM (finished episodes kept)."""

import logging
import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import UserError

log = logging.getLogger("collect")


@hydra.main(version_base="1.3", config_path="../conf", config_name="collect")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.collect import WorkerDied, collect
    from simeval.episodes.store import EpisodeStore
    from simeval.results import RunFolder
    from simeval.sim.rollout import RecordSettings
    from simeval.sim.spec import SUITES_DIR, load_suite, select_specs
    from simeval.sim.splits import heldout_of, load_heldout, split_tasks

    if not cfg.pipeline.get("suite"):
        raise UserError(f"pipeline={cfg.pipeline.name} has no simeval suite yet (pipeline.suite is null)")
    tasks = cfg.tasks if cfg.tasks is None or isinstance(cfg.tasks, str) else list(cfg.tasks)
    suite_dir = SUITES_DIR / cfg.pipeline.suite
    suite = load_suite(suite_dir)
    specs = select_specs(suite, tasks, cfg.task_group)
    if isinstance(cfg.episodes, bool) or not isinstance(cfg.episodes, int) or cfg.episodes < 1:
        raise UserError(f"episodes must be a whole number >= 1, got {cfg.episodes!r}")
    offset = cfg.seed_offset
    if isinstance(offset, bool) or not isinstance(offset, int) or offset < 0:
        raise UserError(f"seed_offset must be a whole number >= 0, got {offset!r}")
    settings = RecordSettings(**OmegaConf.to_container(cfg.record, resolve=True))
    seeds = range(cfg.seed_offset, cfg.seed_offset + cfg.episodes)
    knobs = OmegaConf.to_container(cfg.variation, resolve=True)["knobs"]
    variation, per_task = knobs, None
    heldout = heldout_of(specs, load_heldout(suite_dir, suite))  # read for every split: a broken file is an error
    if cfg.variation.split != "train":  # train: every selected task, held-out ones too (the world model's data)
        pairs = split_tasks(specs, cfg.variation.split, heldout, eval_override=knobs)
        if not pairs:
            raise UserError(f"variation={cfg.variation.split}: none of the selected tasks "
                            f"({', '.join(s.name for s in specs)}) is in that split; see {suite_dir}/splits.yaml "
                            "and the tasks' `variations:`")
        specs, variation, per_task = [s for s, _ in pairs], None, {s.name: v for s, v in pairs}
    try:
        summary = collect(specs, seeds, EpisodeStore(cfg.store), settings, pipeline=cfg.pipeline.name,
                          workers=cfg.workers, variation=variation, task_variations=per_task)
    except KeyboardInterrupt:  # the library has logged what was kept; no traceback for a Ctrl-C
        raise SystemExit(130) from None
    except WorkerDied as e:  # not the user's mistake (exit 2): a resumable failure of the machine
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(1) from None
    run = RunFolder.of(cfg)
    with run.logger() as logger:
        run.write(metric="collect", version="1.0", values=summary)
        logger.log_metrics({"oracle_success": {t: v["rate"] for t, v in summary["tasks"].items()}})
    for task, t in summary["tasks"].items():
        log.info("%-32s %-11s %d/%d oracle successes", task, t["group"], t["success"], t["episodes"])
    log.info("%d new episodes, %d already in %s", len(summary["new"]), summary["skipped"], cfg.store)


if __name__ == "__main__":
    launch(main)
