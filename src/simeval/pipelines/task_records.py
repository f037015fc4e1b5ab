"""The task record every loader returns, and the file readers they share."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from simeval.errors import UserError, yaml_problem

ALL_GROUPS = "all"


class TaskSourceError(UserError):
    """A task source is missing, unreadable or malformed; the message names the file and what is wrong."""


class SourceNotConfigured(TaskSourceError):
    """No source was configured for a pipeline; `hint` names the config key(s) that would provide one."""

    def __init__(self, pipeline: str, hint: str) -> None:
        self.pipeline, self.hint = pipeline, hint
        super().__init__(f"no task source configured for pipeline '{pipeline}': {hint}")


@dataclass(frozen=True)
class TaskText:
    """One task of one group. A task in several groups (GenSim's substring rule) appears once per group.

    `text` is what text metrics embed: the description, or a template of name and description, chosen by
    the loader so each pipeline's texts match what its authors evaluated.
    """

    pipeline: str
    group: str
    name: str
    description: str
    text: str
    metadata: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)


def read_structured(path: str | os.PathLike) -> Any:
    """Parse a YAML, JSON or CSV file (CSV -> list of row dicts). Errors name the file."""
    path = Path(path)
    if path.is_dir():
        raise TaskSourceError(f"{path} is a folder; give a task file (.yaml, .yml, .json or .csv)")
    if not path.is_file():
        raise TaskSourceError(f"task file not found: {path}")
    suffix = path.suffix.lower()
    try:
        text = path.read_text(encoding="utf-8")
        if suffix in (".yaml", ".yml"):
            return yaml.safe_load(text)
        if suffix == ".json":
            return json.loads(text)
        if suffix == ".csv":
            return list(csv.DictReader(text.splitlines()))
    except (yaml.YAMLError, json.JSONDecodeError, csv.Error, UnicodeDecodeError) as e:
        raise TaskSourceError(f"cannot parse {path}: {yaml_problem(e)}") from e
    raise TaskSourceError(f"{path}: unsupported file type '{suffix}' (expected .yaml, .yml, .json or .csv)")


def read_list(path: str | os.PathLike, what: str) -> list:
    """A file holding a list, or a mapping whose `tasks:` key holds one (the layout of exported task lists)."""
    data = read_structured(path)
    if isinstance(data, dict) and "tasks" in data:
        data = data["tasks"]
    if not isinstance(data, list):
        raise TaskSourceError(f"{path}: expected a list of {what} (or a mapping with `tasks:`)")
    return data


def require_text(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise TaskSourceError(f"{where}: expected a non-empty string, got {value!r}")
    return value


def groups_of(tasks: list[TaskText]) -> list[str]:
    """Group names in first-seen order."""
    return list(dict.fromkeys(t.group for t in tasks))


def select_group(tasks: list[TaskText], group: str) -> list[TaskText]:
    """The tasks of one group, or of every group concatenated (`all`). Unknown groups list the valid ones."""
    if group == ALL_GROUPS:
        return list(tasks)
    chosen = [t for t in tasks if t.group == group]
    if not chosen:
        available = ", ".join(groups_of(tasks) + [ALL_GROUPS])
        raise TaskSourceError(f"unknown task_group '{group}'; available: {available}")
    return chosen
