"""GenSim tasks: a static parse of a GenSim checkout (no import of GenSim), or the authors' grouped text file.

Registry rules followed (cliport/tasks/__init__.py and cliport/generated_tasks/__init__.py):
  - template tasks are the keys of the dict `names` in cliport/tasks/__init__.py, each naming a class defined
    in some cliport/tasks/*.py;
  - each cliport/generated_tasks/<stem>.py registers one task named <stem> with '_' -> '-', merged into `names`.
Description = the class's own docstring exactly as `cls.__doc__` gives it, or the literal "None" when absent
(that is what the authors' evaluation embedded). Groups follow the authors' substring rule on the task name.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path

from simeval.pipelines.task_records import TaskText, TaskSourceError, read_structured, require_text

PIPELINE = "gensim"
# Authors' rule: a task belongs to every group whose keyword is a substring of its registered name.
SUBSTRING_GROUPS = {"stack": "stacking", "place": "placement", "pile": "piles", "build": "assembling"}
DEFAULT_TEMPLATE = "Task: {name} \n Description: {description}"


def _parse(path: Path) -> ast.Module:
    try:
        return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    except (SyntaxError, UnicodeDecodeError) as e:
        raise TaskSourceError(f"cannot parse {path}: {e}") from e


def _class_docs(module: ast.Module) -> dict[str, str | None]:
    return {
        node.name: ast.get_docstring(node, clean=False)
        for node in module.body
        if isinstance(node, ast.ClassDef)
    }


def _registry_names(init: Path) -> dict[str, str]:
    """Keys of the `names = {...}` dict -> class name (the last attribute of `tasks.Foo` or `Foo`)."""
    for node in _parse(init).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "names" for t in node.targets):
            if not isinstance(node.value, ast.Dict):
                break
            out = {}
            for k, v in zip(node.value.keys, node.value.values):
                if isinstance(k, ast.Constant) and isinstance(k.value, str):
                    out[k.value] = v.attr if isinstance(v, ast.Attribute) else getattr(v, "id", None)
            return out
    raise TaskSourceError(f"{init}: no `names = {{...}}` registry dict found")


def registered_names(root: str | os.PathLike) -> list[str]:
    """Every task name GenSim's registry gives (template keys, then generated files), grouped or not."""
    root = Path(root).expanduser()
    gen_dir = root / "cliport" / "generated_tasks"
    generated = [py.stem.replace("_", "-") for py in sorted(gen_dir.glob("*.py")) if py.stem != "__init__"] \
        if gen_dir.is_dir() else []
    return [*_registry_names(root / "cliport" / "tasks" / "__init__.py"), *generated]


def gensim_groups(name: str) -> list[str]:
    return [group for key, group in SUBSTRING_GROUPS.items() if key in name]


def load_gensim_checkout(root: str | os.PathLike, text_template: str = DEFAULT_TEMPLATE) -> list[TaskText]:
    """Every registered task that falls in a group, once per group it falls in."""
    root = Path(root).expanduser()
    tasks_dir, gen_dir = root / "cliport" / "tasks", root / "cliport" / "generated_tasks"
    if not (tasks_dir / "__init__.py").is_file():
        raise TaskSourceError(f"{root} is not a GenSim checkout: {tasks_dir / '__init__.py'} not found")
    class_docs: dict[str, str | None] = {}
    for py in sorted(tasks_dir.glob("*.py")):
        class_docs.update(_class_docs(_parse(py)))
    registry: list[tuple[str, str | None, str]] = []
    for name, cls in _registry_names(tasks_dir / "__init__.py").items():
        if cls not in class_docs:
            raise TaskSourceError(f"{tasks_dir / '__init__.py'}: task '{name}' names class {cls}, defined nowhere")
        registry.append((name, class_docs[cls], "template"))
    for py in sorted(gen_dir.glob("*.py")) if gen_dir.is_dir() else []:
        if py.stem == "__init__":
            continue
        docs = _class_docs(_parse(py))
        if not docs:
            raise TaskSourceError(f"{py}: no class defined")
        camel = "".join(part.capitalize() for part in py.stem.split("_"))
        cls = camel if camel in docs else next(iter(docs))
        registry.append((py.stem.replace("_", "-"), docs[cls], "generated"))
    out = []
    for name, doc, origin in registry:
        description = doc if doc is not None else "None"
        for group in gensim_groups(name):
            out.append(TaskText(PIPELINE, group, name, description, text_template.format(name=name, description=description),
                            {"origin": origin}))
    return out


def load_grouped_texts(
    path: str | os.PathLike, pipeline: str, group_aliases: dict[str, str] | None = None
) -> list[TaskText]:
    """A YAML/JSON mapping group -> list of strings, verbatim and in order, duplicates included."""
    return grouped_tasks(read_structured(path), path, pipeline, group_aliases)


def grouped_tasks(data, path: str | os.PathLike, pipeline: str, group_aliases: dict[str, str] | None = None
                  ) -> list[TaskText]:
    """Tasks from an already parsed mapping group -> list of strings (`path` names it in errors)."""
    if not isinstance(data, dict) or not data:
        raise TaskSourceError(f"{path}: expected a mapping of group -> list of strings, got {type(data).__name__}")
    aliases = dict(group_aliases or {})
    out = []
    for key, items in data.items():
        if not isinstance(items, list):
            raise TaskSourceError(f"{path}: group '{key}' must be a list of strings, got {type(items).__name__}")
        group = aliases.get(str(key), str(key))
        for i, item in enumerate(items):
            text = require_text(item, f"{path}: group '{key}' item {i}")
            name = text.split("\n", 1)[0].removeprefix("Task:").strip() if text.startswith("Task:") else f"{key}-{i}"
            out.append(TaskText(pipeline, group, name, text, text, {"index": i}))
    return out
