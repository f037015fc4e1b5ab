"""BBSEA tasks: from a BBSEA output folder (`trajectory/<scene>/<task description>/...`) or a list of strings.

Groups follow the authors' rule: `drawer` if the description mentions a drawer, else `table-top`.
"""

from __future__ import annotations

import os
from pathlib import Path

from simeval.pipelines.task_records import TaskText, TaskSourceError, read_list, require_text

PIPELINE = "bbsea"


def bbsea_group(description: str) -> str:
    return "drawer" if "drawer" in description.lower() else "table-top"


def utf8_name(path: Path) -> str:
    """The folder's name, which is a task description here. A name that is not valid UTF-8 (a folder copied from
    a system with another encoding) would fail later, far from its cause, when written to JSON, HDF5 or a
    terminal; it is a TaskSourceError naming the folder with the bad bytes escaped."""
    try:
        path.name.encode("utf-8")
    except UnicodeEncodeError:
        shown = os.fsencode(path).decode("utf-8", "backslashreplace")
        raise TaskSourceError(f"{shown}: folder name is not valid UTF-8; rename it (e.g. convmv -f latin1 -t utf8 "
                              "--notest)") from None
    return path.name


def load_bbsea_output(root: str | os.PathLike) -> list[TaskText]:
    """One task per (scene, task-description folder). `root` is the output folder or its `trajectory/`."""
    root = Path(root).expanduser()
    traj = root / "trajectory" if (root / "trajectory").is_dir() else root
    scenes = sorted(p for p in traj.iterdir() if p.is_dir()) if traj.is_dir() else []
    out = []
    for scene in scenes:
        for task_dir in sorted(p for p in scene.iterdir() if p.is_dir()):
            desc, scene_name = utf8_name(task_dir), utf8_name(scene)
            out.append(TaskText(PIPELINE, bbsea_group(desc), f"{scene_name}/{desc}", desc, desc, {"scene": scene_name}))
    if not out:
        raise TaskSourceError(f"{root}: no BBSEA tasks found (expected trajectory/<scene>/<task description>/)")
    return out


def load_bbsea_list(path: str | os.PathLike) -> list[TaskText]:
    data = read_list(path, "task descriptions")
    out = []
    for i, item in enumerate(data):
        desc = require_text(item, f"{path}: item {i}")
        out.append(TaskText(PIPELINE, bbsea_group(desc), f"task-{i}", desc, desc))
    return out
