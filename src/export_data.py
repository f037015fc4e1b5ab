"""Export one pipeline's episodes of the store as a LeRobotDataset v3.0 (simeval.pipelines.lerobot_format), so
episodes simeval collected or imported train a LeRobot policy unchanged."""

import logging

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import UserError, require_choice

log = logging.getLogger("export_data")


@hydra.main(version_base="1.3", config_path="../conf", config_name="export_data")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from pathlib import Path

    from simeval.episodes.store import pipeline_episodes
    from simeval.pipelines.lerobot_format import export_lerobot
    from simeval.results import RunFolder

    require_choice("format", cfg.format, ("lerobot",))
    if not cfg.out:
        raise UserError("out is not set: out=/path/to/new_dataset")
    if cfg.fps is not None and (isinstance(cfg.fps, bool) or not isinstance(cfg.fps, (int, float)) or cfg.fps <= 0):
        raise UserError(f"fps={cfg.fps!r}: expected frames per second > 0 (null: the episodes' control rate)")
    metas = pipeline_episodes(cfg.episodes.store, cfg.episodes.pipeline, cfg.episodes.group)
    out = Path(str(cfg.out)).expanduser()
    if out.exists() and not out.is_dir():
        raise UserError(f"out={cfg.out}: is a file; give a folder for the new dataset")
    if out.exists() and any(out.iterdir()) and not cfg.overwrite:
        raise UserError(f"out={cfg.out} exists and is not empty; give another folder, or overwrite=true to replace "
                        "it")
    # episode_index follows the seeds, so a dataset imported from LeRobot goes back with its own episode order
    metas.sort(key=lambda m: (m["seed"], m["task"], m["variation_id"]))
    summary = export_lerobot([m["path"] for m in metas], out, robot_type=str(cfg.robot_type), fps=cfg.fps)
    RunFolder.of(cfg).write(metric="export", version="1.0", values=summary)
    log.info("lerobot: %d episodes, %d frames, %d tasks at %s fps -> %s", summary["episodes"], summary["frames"],
             summary["tasks"], summary["fps"], out)


if __name__ == "__main__":
    launch(main)
