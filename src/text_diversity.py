"""Text diversity of a pipeline's task descriptions (paper Eq. 1, Table 3). See conf/text_diversity.yaml."""

import logging

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.config_schemas import TextDiversityConfig, check_values
from simeval.errors import require_choice, require_folder

log = logging.getLogger("text_diversity")


@hydra.main(version_base="1.3", config_path="../conf", config_name="text_diversity")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from simeval.measures.text_diversity.run import check_settings, log_groups, text_diversity_by_group
    from simeval.embeddings import CachedEmbedder, EmbeddingCache
    from simeval.measures.text_diversity.table3 import run_record, tasks_fingerprint
    from simeval.results import RunFolder
    from simeval.pipelines.task_texts import SourceNotConfigured, load_tasks, source_options

    check_values(cfg, TextDiversityConfig)
    check_settings(**cfg.metrics)  # before the tasks are read or the model loaded
    require_choice("on_missing_source", cfg.on_missing_source, ("error", "record"))
    require_folder("cache_dir", cfg.cache_dir)
    run = RunFolder.of(cfg)
    p = run.config["pipeline"]
    record = run_record(p["name"], p["source"], cfg.task_group, run.config["embedding"], run.config["metrics"],
                        cfg.seed, run.overrides)
    try:
        tasks = load_tasks(p["name"], p["source"], **source_options(p))
    except SourceNotConfigured as e:
        if cfg.on_missing_source != "record":
            raise
        run.write(values={}, status="missing", missing_hint=e.hint, **record)
        log.warning("%s: recorded as missing (%s)", p["name"], e.hint)
        return
    record["identity"]["tasks_sha"] = tasks_fingerprint(tasks)
    embedder = CachedEmbedder(instantiate(cfg.embedding.backend), EmbeddingCache(f"{cfg.cache_dir}/embeddings.sqlite"))
    with run.logger() as logger:
        values = text_diversity_by_group(tasks, embedder.encode, cfg.task_group, seed=cfg.seed, **cfg.metrics)
        path = run.write(values=values, embedded=embedder.last_misses, **record)
        logger.log_metrics(values)
    log_groups(values, p["name"], cfg.embedding.name)
    log.info("wrote %s", path)


if __name__ == "__main__":
    launch(main)
