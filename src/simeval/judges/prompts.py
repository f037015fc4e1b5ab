"""Prompt templates: editable text files. A template holds a system part and a user part separated by a line
`---user---`; `{description}` (and `{captions}` for the caption path) are filled in. The sha256 of the file's
text is recorded with every score, so a changed rubric never mixes with old scores in the cache or tables."""

from __future__ import annotations

import hashlib
import os
import string
from dataclasses import dataclass
from pathlib import Path

SEPARATOR = "---user---"


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


def load_template(path: str | os.PathLike, base_dir: str | os.PathLike | None = None) -> PromptTemplate:
    p = Path(path).expanduser()
    if not p.is_absolute() and base_dir is not None:
        p = Path(base_dir) / p
    if not p.is_file():
        raise FileNotFoundError(f"prompt template not found: {p}")
    text = p.read_text(encoding="utf-8")
    if SEPARATOR not in text:
        raise ValueError(f"{p}: a template needs a line '{SEPARATOR}' between the system and the user part")
    system, user = (part.strip() for part in text.split(SEPARATOR, 1))
    fields = {f for _, f, _, _ in string.Formatter().parse(system + user) if f}
    unknown = fields - {"description", "captions", "n_images"}
    if unknown:
        raise ValueError(f"{p}: unknown placeholder(s) {sorted(unknown)}; allowed: description, captions, n_images")
    return PromptTemplate(p.stem, system, user, hashlib.sha256(text.encode()).hexdigest())
