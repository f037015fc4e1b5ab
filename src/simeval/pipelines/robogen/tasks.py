"""RoboGen tasks: from a checkout's `example_tasks/*/*.yaml`, or from a YAML/JSON/CSV file of records.

Table-top vs ground (our rule, written down because the paper's exact list is unpublished): a task is
`table-top` iff its config has `use_table: true` AND its first articulated object (`type: urdf`) has
`on_table: true`; otherwise `ground` (RoboGen forces every object onto the floor when use_table is false).
"""

from __future__ import annotations

import os
from pathlib import Path

import yaml

from simeval.errors import yaml_problem
from simeval.pipelines.task_records import TaskText, TaskSourceError, read_list, require_text

PIPELINE = "robogen"
DEFAULT_TEMPLATE = "{name}: {description}"
LABEL_TO_GROUP = {"table-top": "table-top", "tabletop": "table-top", "table": "table-top", "ground": "ground"}


def placement_group(config: list) -> str:
    use_table = any(isinstance(d, dict) and d.get("use_table") is True for d in config)
    articulated = [d for d in config if isinstance(d, dict) and d.get("type") == "urdf"]
    on_table = bool(articulated) and articulated[0].get("on_table") is True
    return "table-top" if use_table and on_table else "ground"


def load_robogen_checkout(root: str | os.PathLike, text_template: str = DEFAULT_TEMPLATE) -> list[TaskText]:
    base = Path(root).expanduser() / "example_tasks"
    if not base.is_dir():
        raise TaskSourceError(f"{root} is not a RoboGen checkout: {base} not found")
    out = []
    for path in sorted(base.glob("*/*.yaml")):
        try:
            config = yaml.safe_load(path.read_text(encoding="utf-8"))
        except yaml.YAMLError as e:
            raise TaskSourceError(f"cannot parse {path}: {yaml_problem(e)}") from e
        if not isinstance(config, list):
            continue  # other YAML files (e.g. distractor configs) are not task configs
        meta = next((d for d in config if isinstance(d, dict) and "task_description" in d), None)
        if meta is None:
            continue
        name = require_text(meta.get("task_name"), f"{path}: task_name")
        desc = require_text(meta.get("task_description"), f"{path}: task_description")
        out.append(TaskText(PIPELINE, placement_group(config), name, desc, text_template.format(name=name, description=desc),
                        {"config_file": str(path)}))
    if not out:
        raise TaskSourceError(f"{base}: no task configs (*/*.yaml with task_name and task_description) found")
    return out


def load_robogen_records(path: str | os.PathLike, text_template: str = DEFAULT_TEMPLATE) -> list[TaskText]:
    """Records with task_name/name, task_description/description and placement_label/group; a top-level
    `tasks:` key is accepted (the layout of an exported task list)."""
    data = read_list(path, "task records")
    out = []
    for i, rec in enumerate(data):
        if not isinstance(rec, dict):
            raise TaskSourceError(f"{path}: record {i} is not a mapping: {rec!r}")
        name = require_text(rec.get("task_name", rec.get("name")), f"{path}: record {i} task_name")
        desc = require_text(rec.get("task_description", rec.get("description")), f"{path}: record {i} task_description")
        label = str(rec.get("placement_label", rec.get("group", ""))).lower()
        if label not in LABEL_TO_GROUP:
            raise TaskSourceError(f"{path}: record {i} ('{name}') has group {label!r}; expected table-top or ground")
        out.append(TaskText(PIPELINE, LABEL_TO_GROUP[label], name, desc, text_template.format(name=name, description=desc)))
    return out
