"""Tasks of any pipeline from a user's YAML/JSON/CSV file, in one of three shapes:
  - a mapping group -> list of strings;
  - a plain list of strings (one group, named after the file stem);
  - records with `name`, `description` and `group` (CSV columns or YAML/JSON mappings).
"""

from __future__ import annotations

import os
from pathlib import Path

from simeval.pipelines.gensim.tasks import grouped_tasks
from simeval.pipelines.task_records import TaskText, TaskSourceError, read_structured, require_text


def load_custom(path: str | os.PathLike, pipeline: str = "custom", text_template: str = "{description}") -> list[TaskText]:
    data = read_structured(path)
    if isinstance(data, dict):
        return grouped_tasks(data, path, pipeline)
    if not isinstance(data, list) or not data:
        raise TaskSourceError(f"{path}: expected a mapping group -> list, a list of strings, or a list of records")
    if all(isinstance(x, str) for x in data):
        group = Path(path).stem
        texts = [require_text(x, f"{path}: item {i}") for i, x in enumerate(data)]
        return [TaskText(pipeline, group, f"{group}-{i}", t, t) for i, t in enumerate(texts)]
    out = []
    for i, rec in enumerate(data):
        if not isinstance(rec, dict):
            raise TaskSourceError(f"{path}: item {i} is neither a string nor a record: {rec!r}")
        missing = [k for k in ("name", "description", "group") if k not in rec]
        if missing:
            raise TaskSourceError(f"{path}: record {i} lacks {', '.join(missing)} (needs name, description, group)")
        name = require_text(rec["name"], f"{path}: record {i} name")
        desc = require_text(rec["description"], f"{path}: record {i} description")
        group = require_text(str(rec["group"]), f"{path}: record {i} group")
        out.append(TaskText(pipeline, group, name, desc, text_template.format(name=name, description=desc)))
    return out
