"""Text diversity of a pipeline's task descriptions (paper Eq. 1, Table 3). See conf/text_diversity.yaml."""

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import UserError, require_folder

log = logging.getLogger("text_diversity")


@hydra.main(version_base="1.3", config_path="../conf", config_name="text_diversity")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from simeval.diversity import text_diversity_by_group
    from simeval.embeddings import CachedEmbedder, EmbeddingCache
    from simeval.metrics.text_diversity import METRIC_VERSION
    from simeval.results import RunFolder
    from simeval.report.text_diversity import tasks_fingerprint
    from simeval.tasks import SourceNotConfigured, load_tasks

    if cfg.on_missing_source not in ("error", "record"):
        raise UserError(f"on_missing_source={cfg.on_missing_source!r}: expected error or record")
    require_folder("cache_dir", cfg.cache_dir)
    run = RunFolder.of(cfg)
    config = run.config
    backend = config["embedding"]["backend"]
    # what the numbers are of (see simeval.results.make_identity); the report merges runs by it
    identity = dict(pipeline=cfg.pipeline.name, source=cfg.pipeline.source, tasks_sha=None, task_group=cfg.task_group,
                    embedding=cfg.embedding.name, model=backend.get("model_id") or backend.get("model"),
                    settings=config["metrics"])
    record = dict(metric="text_diversity", version=METRIC_VERSION, seed=cfg.seed, overrides=run.overrides,
                  pipeline=cfg.pipeline.name, embedding=cfg.embedding.name, identity=identity)
    p = cfg.pipeline
    try:
        tasks = load_tasks(p.name, p.source, root=p.root, grouped_file=p.grouped_file, tasks_path=p.tasks_path,
                           suite=p.suite, text_template=p.text_template, group_aliases=p.group_aliases)
    except SourceNotConfigured as e:
        if cfg.on_missing_source != "record":
            raise
        run.write(values={}, status="missing", missing_hint=e.hint, **record)
        log.warning("%s: recorded as missing (%s)", p.name, e.hint)
        return
    identity["tasks_sha"] = tasks_fingerprint(tasks)
    embedder = CachedEmbedder(instantiate(cfg.embedding.backend), EmbeddingCache(Path(cfg.cache_dir) / "embeddings.sqlite"))
    with run.logger() as logger:
        values = text_diversity_by_group(tasks, embedder.encode, cfg.task_group, seed=cfg.seed, **cfg.metrics)
        path = run.write(values=values, embedded=embedder.last_misses, **record)
        logger.log_metrics(values)
    for group, v in values.items():
        log.info("%s/%s [%s] n=%d div=%s", p.name, group, cfg.embedding.name, v["n"],
                 f"{v['div']:.4f}" if "div" in v else v.get("error"))
    log.info("wrote %s", path)


if __name__ == "__main__":
    launch(main)
