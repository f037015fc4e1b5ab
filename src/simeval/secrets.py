"""Keeping secrets out of configs, logs, `result.json` and W&B.

Two rules: (1) values under keys that name a secret (`api_key`, `password`, `authorization`, `access_token`, ...)
are redacted, while counts such as `max_tokens` or `image_tokens` are not; (2) a value that *looks* like a
credential (an OpenAI/Anthropic-style `sk-` key, a Hugging Face or GitHub token, a bearer token) is redacted wherever it appears, and on the
command line it stops the run before Hydra saves the overrides. Bare hex strings (W&B, Azure keys) are not
matched by shape: they cannot be told from the hashes and git shas a run legitimately records.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Any

REDACTED = "<redacted>"
# Whole key names (case-insensitive) that hold secrets; `*_env` keys hold a variable's *name* and are kept.
_SECRET_KEY = re.compile(
    r"^(.*[_-])?(api[_-]?key|apikey|secret|secret[_-]?key|password|passwd|authorization|credentials?|"
    r"(access|auth|bearer|refresh|id|hf|wandb|github|gh)[_-]?token|token)$",
    re.IGNORECASE,
)
_KEY_SHAPES: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("an OpenAI-style key 'sk-...'", re.compile(r"^sk-[A-Za-z0-9_\-]{16,}$")),
    ("a Hugging Face token 'hf_...'", re.compile(r"^hf_[A-Za-z0-9]{20,}$")),
    ("a GitHub token", re.compile(r"^(ghp|gho|ghu|ghs|github_pat)_[A-Za-z0-9_]{20,}$")),
    ("a bearer token", re.compile(r"^Bearer\s+\S{8,}$", re.IGNORECASE)),
)


def is_secret_key(key: str) -> bool:
    return not key.endswith("_env") and bool(_SECRET_KEY.match(key))


def key_shape(value: Any) -> str | None:
    """Which kind of credential `value` looks like, or None."""
    if not isinstance(value, str):
        return None
    v = value.strip()
    for why, pattern in _KEY_SHAPES:
        if pattern.match(v):
            return why
    return None


def redact_secrets(obj: Any) -> Any:
    """A copy of obj with secret-named keys' values and key-shaped values replaced by `<redacted>`."""
    if isinstance(obj, Mapping):
        return {str(k): (REDACTED if is_secret_key(str(k)) and v is not None else redact_secrets(v))
                for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [redact_secrets(v) for v in obj]
    return REDACTED if key_shape(obj) else obj


def key_shaped_overrides(overrides: Iterable[str]) -> list[tuple[str, str]]:
    """(key, reason) for each `key=value` override whose value looks like a credential."""
    found = []
    for arg in overrides:
        if "=" not in arg or arg.startswith("-"):
            continue
        key, _, value = arg.partition("=")
        why = key_shape(value.strip("'\""))
        if why:
            found.append((key.lstrip("+~"), why))
    return found


def find_key_shaped(obj: Any, path: str = "") -> list[tuple[str, str]]:
    """(dotted key, reason) for every key-shaped value in a nested config."""
    if isinstance(obj, Mapping):
        return [hit for k, v in obj.items() for hit in find_key_shaped(v, f"{path}.{k}" if path else str(k))]
    if isinstance(obj, (list, tuple)):
        return [hit for i, v in enumerate(obj) for hit in find_key_shaped(v, f"{path}[{i}]")]
    why = key_shape(obj)
    return [(path, why)] if why else []
