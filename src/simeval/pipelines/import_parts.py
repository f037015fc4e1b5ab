"""What every importer of simeval.pipelines.importers shares (kept apart so a format in a module of its own, such as
simeval.pipelines.lerobot_format, uses them without importing every other format): the answer for an episode the
store holds already, the error for a folder without a format's files, and the resizing of frames."""

from __future__ import annotations

import hashlib
import re

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simeval.episodes.episode import EpisodeFormatError
from simeval.errors import UserError

# (pipeline, task, seed) -> already in the store? Importers ask before loading a file, so a resumed import
# does not re-read what it already wrote.
IsStored = Callable[[str, str, int], bool]


def never_stored(pipeline: str, task: str, seed: int) -> bool:
    return False


@dataclass(frozen=True)
class Stored:
    """An episode the store already holds; its source file was not loaded."""

    pipeline: str
    task: str
    seed: int


class NoDemonstrations(EpisodeFormatError):
    """`root` holds none of a format's files; `what` says what it should hold (import_into_store names its key)."""

    def __init__(self, root: Path, what: str) -> None:
        super().__init__(f"{root}: {what}")
        self.what = what


def image_size_option(value, key: str = "image_size") -> tuple[int, int] | None:
    """None (keep the source resolution) or [H, W] with both >= 1, as a tuple; else a UserError naming `key`."""
    if value is None:
        return None
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) and x >= 1 for x in value))
    if not ok:
        raise UserError(f"{key} must be null (keep the source size) or [H, W] with whole numbers H, W >= 1, "
                        f"got {value!r}")
    return int(value[0]), int(value[1])


def resize_frames(frames: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    size = image_size_option(size)
    if size is None or tuple(frames.shape[1:3]) == tuple(size):
        return np.ascontiguousarray(frames, dtype=np.uint8)
    from PIL import Image

    h, w = size
    return np.stack([np.asarray(Image.fromarray(f).resize((w, h), Image.BILINEAR)) for f in frames]).astype(np.uint8)


def pipeline_name(name: str) -> str:
    """The pipeline name an imported dataset is stored under by default: its folder's or file's name, with anything
    but letters, digits, '-' and '_' made '_'."""
    return re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "imported"


def task_name(text: str) -> str:
    """A store task name for a task text: its words in lower case joined by '-', at most 64 characters; a text cut
    short (or with no letters) gets 8 characters of its hash, so two long texts never share a name."""
    slug = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    if slug and len(slug) <= 64:
        return slug
    return f"{slug[:55].rstrip('-')}-{hashlib.sha1(text.encode()).hexdigest()[:8]}".lstrip("-")


def sparse_success(rewards: np.ndarray) -> tuple[bool, bool]:
    """(success, known) from a reward sequence: where every reward is 0 or 1 (a sparse success reward, as
    robosuite's and many LeRobot datasets'), success is a reward of 1 anywhere; otherwise unknown."""
    r = np.asarray(rewards, float).ravel()
    if r.size and np.isin(r, (0.0, 1.0)).all():
        return bool((r == 1.0).any()), True
    return False, False
