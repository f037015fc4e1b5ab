"""Command-line conveniences shared by the Hydra entrypoints under `src/`."""

from __future__ import annotations

import sys

MULTIRUN_FLAGS = ("-m", "--multirun")


def move_multirun_flag_first(argv: list[str]) -> list[str]:
    """Return argv with `-m`/`--multirun` moved right after the program name.

    Users type `python src/diversity.py pipeline=bbsea -m episodes=10,20,40`; Hydra's argparse rejects a flag
    after an override. Only whole tokens move, so an override whose value is "-m" (`key=-m`) is untouched.
    """
    program, rest = argv[:1], argv[1:]
    if "--" in rest:  # everything after a bare `--` is positional by convention
        cut = rest.index("--")
        head, tail = rest[:cut], rest[cut:]
    else:
        head, tail = rest, []
    flags = [a for a in head if a in MULTIRUN_FLAGS]
    if not flags:
        return list(argv)
    others = [a for a in head if a not in MULTIRUN_FLAGS]
    return program + ["--multirun"] + others + tail


def allow_multirun_anywhere() -> None:
    """Rewrite sys.argv in place; call before the `@hydra.main` function."""
    sys.argv[:] = move_multirun_flag_first(sys.argv)
