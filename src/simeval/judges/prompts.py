"""Prompt templates: editable text files. A template holds a system part and a user part separated by a line
`---user---`; `{description}` (and `{captions}` for the caption path) are filled in. The sha256 of the file's
text is recorded with every score, so a changed rubric never mixes with old scores in the cache or tables.

The default templates ship inside the package (`simeval/judges/templates/*.txt`, package data), so an installed
simeval finds them without a checkout; they are named `builtin:NAME` (e.g. `builtin:task_completion`). Any other
value is a path to your own file (relative paths are relative to the working directory, or to `base_dir`)."""

from __future__ import annotations

import hashlib
import os
import string
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

SEPARATOR = "---user---"
BUILTIN = "builtin:"


@dataclass(frozen=True)
class PromptTemplate:
    name: str
    system: str
    user: str
    sha256: str

    def render(self, **fields: str) -> tuple[str, str]:
        try:
            return self.system.format(**fields), self.user.format(**fields)
        except KeyError as e:
            raise ValueError(f"template '{self.name}' needs field {e}; given {sorted(fields)}") from e


def builtin_names() -> list[str]:
    return sorted(p.name[:-4] for p in resources.files("simeval.judges").joinpath("templates").iterdir()
                  if p.name.endswith(".txt"))


def _read(path: str | os.PathLike, base_dir: str | os.PathLike | None) -> tuple[str, str, str]:
    """(name, where, text) of a template given as `builtin:NAME` or a path."""
    from simeval.errors import UserError

    spec = str(path)
    if spec.startswith(BUILTIN):
        name = spec[len(BUILTIN):]
        res = resources.files("simeval.judges").joinpath("templates", f"{name}.txt")
        if not name or not res.is_file():
            raise UserError(f"prompt template {spec!r} does not exist; builtin templates: "
                            f"{', '.join(BUILTIN + n for n in builtin_names())}")
        return name, spec, res.read_text(encoding="utf-8")
    p = Path(path).expanduser()
    if not p.is_absolute() and base_dir is not None:
        p = Path(base_dir) / p
    if not p.is_file():
        raise UserError(f"prompt template not found: {p} (give a file, or builtin:NAME with NAME one of "
                        f"{', '.join(builtin_names())})")
    return p.stem, str(p), p.read_text(encoding="utf-8")


def load_template(path: str | os.PathLike, base_dir: str | os.PathLike | None = None) -> PromptTemplate:
    from simeval.errors import UserError

    name, where, text = _read(path, base_dir)
    if SEPARATOR not in text:
        raise UserError(f"{where}: a template needs a line '{SEPARATOR}' between the system and the user part")
    system, user = (part.strip() for part in text.split(SEPARATOR, 1))
    fields = {f for _, f, _, _ in string.Formatter().parse(system + user) if f}
    unknown = fields - {"description", "captions", "n_images"}
    if unknown:
        raise UserError(f"{where}: unknown placeholder(s) {sorted(unknown)}; allowed: description, captions, "
                        f"n_images")
    return PromptTemplate(name, system, user, hashlib.sha256(text.encode()).hexdigest())
