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

    from simeval.episodes.store import EpisodeStore
    from simeval.pipelines.lerobot_format import export_lerobot
    from simeval.results import RunFolder

    require_choice("format", cfg.format, ("lerobot",))
    src = cfg.episodes
    if not src.pipeline:
        raise UserError(f"episodes.pipeline is not set: episodes.pipeline=<a pipeline of the store {src.store}>")
    if not cfg.out:
        raise UserError("out is not set: out=/path/to/new_dataset")
    if not Path(str(src.store)).is_dir():
        raise UserError(f"episodes.store={src.store}: no such folder")
    store = EpisodeStore(src.store)
    held = sorted(p.name for p in Path(str(src.store)).iterdir() if p.is_dir() and store.paths(p.name))
    if src.pipeline not in held:
        raise UserError(f"episodes.pipeline={src.pipeline}: the store {src.store} holds no episodes of it (it holds "
                        f"{', '.join(held) or 'none'})")
    metas = store.index(src.pipeline, src.group)
    if not metas:
        groups = sorted({m["group"] for m in store.index(src.pipeline)})
        raise UserError(f"episodes.group={src.group}: pipeline {src.pipeline} has no such group (it has "
                        f"{', '.join(groups)})")
    out = Path(str(cfg.out)).expanduser()
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
