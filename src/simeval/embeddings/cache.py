"""On-disk embedding cache: SQLite, keyed by sha256(model id, text), so no text is embedded twice by a model.
A damaged or locked file stops the run with one line naming the file (`simeval.sqlite_files`)."""

from __future__ import annotations

import hashlib
import os
import sqlite3
from pathlib import Path

import numpy as np

from simeval.sqlite_files import friendly_errors

ADVICE = ("delete it or move it aside (with any {sidecars} beside it), then re-run; it only saves recomputing "
          "embeddings, and the re-run rebuilds it")


def embedding_key(model_id: str, text: str) -> str:
    return hashlib.sha256(f"{model_id}\x00{text}".encode()).hexdigest()


class EmbeddingCache:
    def __init__(self, path: str | os.PathLike, *, timeout_s: float = 30.0) -> None:
        """`timeout_s`: how long to wait for another process's write lock before stopping with an error."""
        self.path, self.timeout_s = Path(path), timeout_s
        with self._errors():
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=timeout_s)
            self._db.execute("PRAGMA journal_mode=WAL")  # readers never block the writer of a parallel sweep job
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS embeddings (key TEXT PRIMARY KEY, model_id TEXT, dim INTEGER, vec BLOB)"
            )
            self._db.commit()

    def _errors(self):
        return friendly_errors(self.path, what="embedding cache", advice=ADVICE, timeout_s=self.timeout_s)

    def get_many(self, model_id: str, texts: list[str]) -> dict[str, np.ndarray]:
        """text -> float32 vector for the texts already cached."""
        keys = {embedding_key(model_id, t): t for t in texts}
        found: dict[str, np.ndarray] = {}
        key_list = list(keys)
        for i in range(0, len(key_list), 500):  # SQLite limits the number of bound parameters
            chunk = key_list[i : i + 500]
            with self._errors():
                rows = self._db.execute(
                    f"SELECT key, dim, vec FROM embeddings WHERE key IN ({','.join('?' * len(chunk))})", chunk
                ).fetchall()
            for key, dim, blob in rows:
                vec = np.frombuffer(blob, dtype=np.float32)
                if vec.shape != (dim,):
                    continue  # a damaged row is treated as a miss and recomputed
                found[keys[key]] = vec
        return found

    def put_many(self, model_id: str, texts: list[str], vectors: np.ndarray) -> None:
        rows = [
            (embedding_key(model_id, t), model_id, int(v.shape[0]), np.asarray(v, dtype=np.float32).tobytes())
            for t, v in zip(texts, vectors)
        ]
        with self._errors(), self._db:
            self._db.executemany("INSERT OR REPLACE INTO embeddings VALUES (?, ?, ?, ?)", rows)

    def __len__(self) -> int:
        with self._errors():
            return self._db.execute("SELECT COUNT(*) FROM embeddings").fetchone()[0]

    def close(self) -> None:
        self._db.close()
