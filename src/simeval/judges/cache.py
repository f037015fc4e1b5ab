"""SQLite cache of judge calls, keyed by a hash of everything that determines the reply.

A call is written the moment its reply arrives (one transaction per call), so killing the process at any moment
loses no paid call, and a re-run asks only what is not in the cache. Keys include the repeat index and the ask
index (re-asks after an unparseable reply), so a re-run replays exactly the same sequence.

Runs in separate processes sharing one cache file pay each request once: before asking the model, a run takes a
*lease* on the request key (a row: key, owner, host, pid, expiry, renewed by a heartbeat while the call is in
flight). A run that finds another live process's lease waits for that reply (polling with backoff) instead of
asking too; a lease whose owner died (its pid is gone on this host, or it stopped renewing for `lease_s`) is
taken over. `get` (dry runs, replay) never takes leases.

A damaged or locked file stops the run with one line naming the file (`simeval.sqlite_files`).
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import sqlite3
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from simeval.sqlite_files import friendly_errors, use_wal


def request_key(*, provider: str, model: str, template_sha256: str, system: str, user: str,
                image_sha256: list[str], decoding: dict, repeat: int, ask: int, endpoint: str = "") -> str:
    """The cache key of one request. `endpoint` (the normalised URL, or `local:<model dir>`) keeps replies of
    different servers apart even when they answer to the same model name (a loopback smoke-test server and
    api.openai.com both serving "gpt-4o")."""
    blob = json.dumps({"provider": provider, "endpoint": endpoint, "model": model, "template": template_sha256,
                       "system": system, "user": user, "images": image_sha256, "decoding": decoding,
                       "repeat": repeat, "ask": ask}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


@dataclass
class CachedCall:
    key: str
    reply: str
    prompt_tokens: int
    completion_tokens: int
    images: int
    cost_usd: float
    latency_s: float
    created: float


ADVICE = ("it holds replies that were paid for, so move it aside (with any {sidecars} beside it) rather than "
          "delete it, then re-run: a new cache is created and the missing replies are asked, and paid for, again "
          "(sqlite3's .recover may save some of the old ones)")
_CALL_COLUMNS = "key, reply, prompt_tokens, completion_tokens, images, cost_usd, latency_s, created"


def _pid_gone(pid: int) -> bool:
    """True if no process `pid` runs on this machine (a zombie counts as gone: it will never reply)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return False


class JudgeCache:
    def __init__(self, path: str | os.PathLike, *, timeout_s: float = 30.0, lease_s: float = 60.0,
                 max_poll_s: float = 1.0) -> None:
        """`timeout_s`: how long to wait for another process's write lock before stopping with an error;
        `lease_s`: how long a lease lives without renewal (a heartbeat renews it every lease_s/4 while held);
        `max_poll_s`: the longest pause between looks while waiting on another process's call."""
        self.path = Path(path)
        self.timeout_s, self.lease_s, self.max_poll_s = timeout_s, lease_s, max_poll_s
        self.host, self.pid = socket.gethostname(), os.getpid()
        self.owner = f"{self.host}:{self.pid}:{uuid.uuid4().hex[:12]}"
        self.waited = 0  # requests answered by another process's call this cache waited for (for tests/logs)
        self._lock = threading.RLock()
        self._held: set[str] = set()
        self._heartbeat: threading.Thread | None = None
        self._closed = threading.Event()
        with self._errors():
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # isolation_level=None: transactions are explicit (BEGIN IMMEDIATE where a read decides a write)
            self._db = sqlite3.connect(self.path, timeout=timeout_s, check_same_thread=False, isolation_level=None)
            use_wal(self._db, timeout_s=timeout_s)
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS calls (key TEXT PRIMARY KEY, provider TEXT, model TEXT, item TEXT, "
                "metric TEXT, repeat INTEGER, ask INTEGER, reply TEXT, prompt_tokens INTEGER, "
                "completion_tokens INTEGER, images INTEGER, cost_usd REAL, latency_s REAL, created REAL)")
            self._db.execute("CREATE TABLE IF NOT EXISTS leases (key TEXT PRIMARY KEY, owner TEXT, host TEXT, "
                             "pid INTEGER, expires REAL)")

    def _errors(self):
        return friendly_errors(self.path, what="judge cache", advice=ADVICE, timeout_s=self.timeout_s)

    def get(self, key: str) -> CachedCall | None:
        with self._errors(), self._lock:
            row = self._db.execute(f"SELECT {_CALL_COLUMNS} FROM calls WHERE key = ?", (key,)).fetchone()
        return CachedCall(*row) if row else None

    def _live(self, lease: tuple, now: float) -> bool:
        _owner, host, pid, expires = lease
        if expires < now:
            return False
        return not (host == self.host and pid != self.pid and _pid_gone(pid))

    def claim(self, key: str) -> CachedCall | None:
        """The cached call for `key`; or None, and then this cache holds the lease on `key`: ask the model, then
        put() the reply (which ends the lease) or release(key). While another live process (or another thread)
        holds the lease, wait for its reply instead of paying for the same request twice."""
        pause, waited = 0.02, False
        while True:
            with self._errors(), self._lock:
                row = self._db.execute(f"SELECT {_CALL_COLUMNS} FROM calls WHERE key = ?", (key,)).fetchone()
                if row is not None:
                    self.waited += waited
                    return CachedCall(*row)
                lease = self._db.execute("SELECT owner, host, pid, expires FROM leases WHERE key = ?",
                                         (key,)).fetchone()
                if lease is None or not self._live(lease, time.time()):
                    if self._try_lease(key):
                        return None
                    continue  # another process took or answered it between the look and the lock: look again
            time.sleep(pause)
            pause, waited = min(pause * 2, self.max_poll_s), True

    def _try_lease(self, key: str) -> bool:
        """Take the lease on `key` if, under the write lock, there is still no reply and no live lease."""
        db = self._db
        db.execute("BEGIN IMMEDIATE")  # the write lock, so two processes cannot both see "free" and both take it
        try:
            now = time.time()
            lease = db.execute("SELECT owner, host, pid, expires FROM leases WHERE key = ?", (key,)).fetchone()
            taken = db.execute("SELECT 1 FROM calls WHERE key = ?", (key,)).fetchone() is None and (
                lease is None or not self._live(lease, now))
            if taken:
                db.execute("INSERT OR REPLACE INTO leases VALUES (?, ?, ?, ?, ?)",
                           (key, self.owner, self.host, self.pid, now + self.lease_s))
            db.execute("COMMIT")
        except BaseException:
            if db.in_transaction:
                db.execute("ROLLBACK")
            raise
        if taken:
            self._held.add(key)
            self._start_heartbeat()
        return taken

    def release(self, key: str) -> None:
        """Give up the lease on `key` without a reply (the call failed), so a waiting process asks itself. Never
        raises: it runs while another error is on its way up, and an unreleased lease expires anyway."""
        with self._lock:
            self._held.discard(key)
            try:
                self._db.execute("DELETE FROM leases WHERE key = ? AND owner = ?", (key, self.owner))
            except sqlite3.Error:
                pass

    def _start_heartbeat(self) -> None:
        if self._heartbeat is None or not self._heartbeat.is_alive():
            self._heartbeat = threading.Thread(target=self._renew, name="judge-cache-leases", daemon=True)
            self._heartbeat.start()

    def _renew(self) -> None:
        while not self._closed.wait(self.lease_s / 4):
            with self._lock:
                if not self._held:
                    continue
                try:
                    self._db.execute("UPDATE leases SET expires = ? WHERE owner = ?",
                                     (time.time() + self.lease_s, self.owner))
                except sqlite3.Error:
                    continue  # any sqlite error, not only "busy": a dead heartbeat would let the lease lapse and
                    # another run pay for this request; the next beat retries and the lease is good for lease_s

    def put(self, call: CachedCall, *, provider: str, model: str, item: str, metric: str, repeat: int,
            ask: int) -> None:
        """Store a reply and end this cache's lease on its key, in one transaction."""
        with self._errors(), self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.execute(
                    "INSERT OR REPLACE INTO calls VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (call.key, provider, model, item, metric, repeat, ask, call.reply, call.prompt_tokens,
                     call.completion_tokens, call.images, call.cost_usd, call.latency_s, call.created or time.time()))
                self._db.execute("DELETE FROM leases WHERE key = ? AND owner = ?", (call.key, self.owner))
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise
            finally:
                self._held.discard(call.key)  # stored, or failing: either way this cache stops renewing the lease

    def __len__(self) -> int:
        with self._errors(), self._lock:
            return self._db.execute("SELECT COUNT(*) FROM calls").fetchone()[0]

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            for key in list(self._held):
                self.release(key)
            self._db.close()
