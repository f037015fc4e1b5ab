"""Registries that are folders: every module of a package that defines a given attribute (robots: ROBOT, goal
types: GOAL) is found by listing the package, so adding one is adding a file and nothing else names it."""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType
from typing import Any


def modules_defining(package: ModuleType, attribute: str, kind: type) -> dict[str, Any]:
    """{value.name: value} for each module of `package` whose `attribute` is an instance of `kind`."""
    found = {}
    for module in pkgutil.iter_modules(package.__path__):
        value = getattr(importlib.import_module(f"{package.__name__}.{module.name}"), attribute, None)
        if isinstance(value, kind):
            found[value.name] = value
    return found
