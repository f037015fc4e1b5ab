"""SQLite cache of judge calls, keyed by a hash of everything that determines the reply.

A call is written the moment its reply arrives (one transaction per call), so killing the process at any moment
loses no paid call, and a re-run asks only what is not in the cache. Keys include the repeat index and the ask
index (re-asks after an unparseable reply), so a re-run replays exactly the same sequence.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path


def request_key(*, provider: str, model: str, template_sha256: str, system: str, user: str,
                image_sha256: list[str], decoding: dict, repeat: int, ask: int) -> str:
    blob = json.dumps({"provider": provider, "model": model, "template": template_sha256, "system": system,
                       "user": user, "images": image_sha256, "decoding": decoding, "repeat": repeat, "ask": ask},
                      sort_keys=True)
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


class JudgeCache:
    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, timeout=30, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS calls (key TEXT PRIMARY KEY, provider TEXT, model TEXT, item TEXT, "
            "metric TEXT, repeat INTEGER, ask INTEGER, reply TEXT, prompt_tokens INTEGER, completion_tokens INTEGER, "
            "images INTEGER, cost_usd REAL, latency_s REAL, created REAL)"
        )
        self._db.commit()

    def get(self, key: str) -> CachedCall | None:
        with self._lock:
            row = self._db.execute(
                "SELECT key, reply, prompt_tokens, completion_tokens, images, cost_usd, latency_s, created "
                "FROM calls WHERE key = ?", (key,)).fetchone()
        return CachedCall(*row) if row else None

    def put(self, call: CachedCall, *, provider: str, model: str, item: str, metric: str, repeat: int,
            ask: int) -> None:
        with self._lock, self._db:
            self._db.execute(
                "INSERT OR REPLACE INTO calls VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (call.key, provider, model, item, metric, repeat, ask, call.reply, call.prompt_tokens,
                 call.completion_tokens, call.images, call.cost_usd, call.latency_s, call.created or time.time()))

    def __len__(self) -> int:
        with self._lock:
            return self._db.execute("SELECT COUNT(*) FROM calls").fetchone()[0]
