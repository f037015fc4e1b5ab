"""The one exception type for mistakes a user can fix (a bad path, value or file).

Entry points turn a `UserError` into one line on stderr and exit status 2, with no traceback (set
`HYDRA_FULL_ERROR=1` to see it). Library code raises it where it knows the file, key or value at fault; the
message names that thing and what would be valid, e.g.::

    raise UserError(f"{path}: row 7, column 'Human': 'abc' is not a number")
"""

from __future__ import annotations

import dataclasses
import numbers
import types
import typing
from collections.abc import Mapping


USER_ERROR_EXIT = 2  # the exit status of a run stopped by a UserError
REFUSAL_FILE_ENV = "SIMEVAL_REFUSAL_FILE"  # where an entrypoint records why it stopped, for the process that ran it


def read_refusal(path) -> dict | None:
    """What a child run recorded at REFUSAL_FILE_ENV when it stopped on a UserError ({error: its one line,
    episodes_unfit}), or None when it recorded nothing (it finished, or stopped otherwise)."""
    import json
    from pathlib import Path

    path = Path(path)
    return json.loads(path.read_text()) if path.is_file() else None


def yaml_problem(e: Exception) -> str:
    """A YAML parse error as one clause: "line L, column C: <problem> (<context> at line l, column c)". PyYAML's
    own text is five lines whose first ("while parsing a flow sequence") is all a one-line error would keep."""
    problem, mark = getattr(e, "problem", None), getattr(e, "problem_mark", None)
    if not problem or mark is None:
        return " ".join(str(e).split())
    context, at = getattr(e, "context", None), getattr(e, "context_mark", None)
    where = f" ({context} at line {at.line + 1}, column {at.column + 1})" if context and at is not None else ""
    return f"line {mark.line + 1}, column {mark.column + 1}: {problem}{where}"


class UserError(ValueError):
    """A fixable input mistake. Subclasses ValueError so callers that catch ValueError keep working."""


class EpisodesUnfit(UserError):
    """The episodes cannot serve the measure's settings (too short for a window, frames smaller than the model's,
    state layouts that differ). Alone it stops a run like any UserError; a caller that measures whatever episodes
    it is given (src/evaluate.py) reads it, through REFUSAL_FILE_ENV, as "no reading" for that measure rather than
    a mistake in its own settings."""


TYPE_WORDS = {int: "a whole number", float: "a number", bool: "true or false", str: "text", type(None): "null"}


def check_field_types(settings: object, prefix: str) -> None:
    """Each int, float, bool or str field of a settings dataclass (Optional ones may be None) holds a value of its
    type, else a UserError `<prefix>.<field>=<value>: expected <type>`, worded as a typed schema's composition
    error (simeval.config_schemas). Why here: a config group's keys differ by option, so no schema types them; a
    string where a number belongs would otherwise fail deep in a comparison or in torch. Other annotations
    (tuples, lists, mappings) are read by the class itself."""
    hints = typing.get_type_hints(type(settings))
    for f in dataclasses.fields(settings):
        value, kind = getattr(settings, f.name), hints[f.name]
        if not _is_of(value, kind):
            raise UserError(f"{prefix}.{f.name}={'null' if value is None else repr(value)}: expected "
                            + " or ".join(TYPE_WORDS[k] for k in _scalar_kinds(kind)))


def _scalar_kinds(kind) -> list:
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return [k for k in typing.get_args(kind) if k in TYPE_WORDS]
    return [kind] if kind in TYPE_WORDS else []


def _is_of(value, kind) -> bool:
    kinds = _scalar_kinds(kind)
    if not kinds or len(kinds) < len(typing.get_args(kind) or [kind]):  # not (only) scalars: the class reads it
        return True
    # numpy's bool too (values read from files); numpy's numbers are numbers.Integral / numbers.Real
    numpy_bool = type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_")
    is_bool = isinstance(value, bool) or numpy_bool
    return any(value is None if k is type(None) else
               is_bool if k is bool else
               isinstance(value, numbers.Integral) and not is_bool if k is int else
               isinstance(value, numbers.Real) and not is_bool if k is float else
               isinstance(value, str) for k in kinds)


def require_whole(key: str, value: object, low: int = 1) -> None:
    """Raise a UserError naming `key` unless value is an int (not a bool) >= low: configs give strings and floats
    as readily as ints, and a comparison with them fails far from the key that caused it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise UserError(f"{key} must be a whole number >= {low}, got {value!r}")


def require_whole_fields(settings: object, prefix: str, names: tuple[str, ...], low: int = 1) -> None:
    """require_whole for each named field of a settings dataclass, named `<prefix>.<field>` as the config spells it."""
    for name in names:
        require_whole(f"{prefix}.{name}", getattr(settings, name), low)


def require_choice(key: str, value: object, choices: tuple[str, ...]) -> None:
    """Raise a UserError naming `key` and the valid values unless value is one of `choices`."""
    if value not in choices:
        expected = choices[0] if len(choices) == 1 else f"{', '.join(choices[:-1])} or {choices[-1]}"
        raise UserError(f"{key}={value!r}: expected {expected}")


def require_folder(key: str, path: object) -> None:
    """Create the folder a config key names, or raise a UserError naming the key: a path that is a file (or lies
    under one) or cannot be written would otherwise surface as an OSError traceback once a run first writes there,
    which for a checkpoint folder is after the first training steps."""
    import os
    from pathlib import Path

    if path is None or str(path).strip() == "":
        raise UserError(f"{key} is not set; give a folder (it is created if missing)")
    folder = Path(str(path)).expanduser()
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{key}={path}: is a file, not a folder; give a folder (it is created if missing)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{key}={path}: cannot create the folder ({e.strerror or e})") from e
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UserError(f"{key}={path}: the folder is not writable")


def settings_from_dict(cls, d: dict | None, key: str, null: str = "the defaults"):
    """A settings dataclass from a config mapping (None: its defaults); a key it does not have is a UserError
    naming `key` and the valid ones; so is a value that is not a mapping (`protocol.gate=5`). `null`: what null
    stands for at `key`, named in that error."""
    if d is not None and not isinstance(d, Mapping):
        raise UserError(f"{key}={d!r}: expected a mapping of its settings ({', '.join(cls.__dataclass_fields__)}), "
                        f"set one by one ({key}.<setting>=..., with a leading + for one the yaml does not list); "
                        f"or null for {null}")
    d = dict(d or {})
    unknown = set(d) - set(cls.__dataclass_fields__)
    if unknown:
        raise UserError(f"{key}: unknown key(s) {', '.join(sorted(unknown))}; expected "
                        f"{', '.join(cls.__dataclass_fields__)}")
    return cls(**d)
