"""Opening the SQLite caches (judge calls, embeddings) so that a damaged, locked or unopenable file stops the run
with one line naming the file and what to do, instead of a traceback from deep inside sqlite3."""

from __future__ import annotations

import contextlib
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

from simeval.errors import UserError


def sqlite_user_error(path: Path, e: sqlite3.Error, *, what: str, advice: str, timeout_s: float) -> UserError:
    """A UserError for an sqlite3 error on the cache file `path`: locked, unopenable, or damaged (then `advice`,
    where `{sidecars}` names the -wal/-shm files to move with it, says what to do)."""
    said = " ".join(str(e).split()) or type(e).__name__
    if isinstance(e, sqlite3.OperationalError) and ("locked" in said or "busy" in said):
        return UserError(
            f"{path}: the {what} is locked by another process (waited {timeout_s:g} s; sqlite: {said}); another run "
            "may be writing to it, or a program holds a transaction open on it (a sqlite3 shell, a run on a network "
            "filesystem): let it finish or close it, then re-run")
    if isinstance(e, sqlite3.OperationalError) and ("unable to open" in said or "readonly" in said
                                                     or "read-only" in said or "disk I/O" in said):
        return UserError(f"{path}: cannot open or write the {what} (sqlite: {said}); check that its folder exists "
                         "and is writable, or point cache_dir=... elsewhere")
    sidecars = f"{path.name}-wal and {path.name}-shm"  # a stale -wal beside a new file would be replayed into it
    return UserError(f"{path}: the {what} is damaged or not an SQLite file (sqlite: {said}); "
                     + advice.format(sidecars=sidecars))


@contextlib.contextmanager
def friendly_errors(path: Path, *, what: str, advice: str, timeout_s: float) -> Iterator[None]:
    try:
        yield
    except sqlite3.Error as e:
        raise sqlite_user_error(path, e, what=what, advice=advice, timeout_s=timeout_s) from e


def use_wal(db: sqlite3.Connection, *, timeout_s: float) -> None:
    """Put `db` in WAL mode (readers never block the writer of a parallel job), retrying for up to `timeout_s`.

    Why a loop: switching the journal mode needs an exclusive lock, and SQLite answers "database is locked" at once,
    without calling the busy handler, when another process is creating or switching the same new file. Two runs
    started together on a fresh cache hit this about one time in three; the mode is stored in the file, so once
    one of them has switched it the other's pragma is a no-op."""
    deadline, pause = time.monotonic() + timeout_s, 0.01
    while True:
        try:
            db.execute("PRAGMA journal_mode=WAL").fetchone()  # on a filesystem without shared memory it
            return  # stays in its old mode: still correct, only slower
        except sqlite3.OperationalError as e:
            if "locked" not in str(e) and "busy" not in str(e) or time.monotonic() > deadline:
                raise
        time.sleep(pause)
        pause = min(pause * 2, 0.5)
