"""On-disk embedding cache: SQLite, keyed by sha256(model id, text), so no text is embedded twice by a model.
A damaged or locked file stops the run with one line naming the file (`simeval.sqlite_files`). Each stored vector
carries an 8-byte BLAKE2b digest of its bytes: a row whose bytes were damaged inside an intact SQLite page (which
SQLite cannot notice) fails the digest and is recomputed, never used."""

from __future__ import annotations

import hashlib
import os
import sqlite3
from pathlib import Path

import numpy as np

from simeval.sqlite_files import friendly_errors, use_wal

ADVICE = ("delete it or move it aside (with any {sidecars} beside it), then re-run; it only saves recomputing "
          "embeddings, and the re-run rebuilds it")


DIGEST_BYTES = 8


def _digest(data: bytes) -> bytes:
    return hashlib.blake2b(data, digest_size=DIGEST_BYTES).digest()


def _pack(vector: np.ndarray) -> bytes:
    data = np.asarray(vector, dtype=np.float32).tobytes()
    return data + _digest(data)


def _unpack(blob: bytes, dim: int) -> np.ndarray | None:
    """The vector, or None for a damaged row (wrong length, digest mismatch, or written before digests)."""
    data, digest = blob[:-DIGEST_BYTES], blob[-DIGEST_BYTES:]
    if len(blob) != dim * 4 + DIGEST_BYTES or _digest(data) != digest:
        return None
    return np.frombuffer(data, dtype=np.float32)


def embedding_key(model_id: str, text: str) -> str:
    return hashlib.sha256(f"{model_id}\x00{text}".encode()).hexdigest()


class EmbeddingCache:
    def __init__(self, path: str | os.PathLike, *, timeout_s: float = 30.0) -> None:
        """`timeout_s`: how long to wait for another process's write lock before stopping with an error."""
        self.path, self.timeout_s = Path(path), timeout_s
        with self._errors():
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=timeout_s)
            use_wal(self._db, timeout_s=timeout_s)
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
                vec = _unpack(bytes(blob), dim)
                if vec is not None:  # a damaged row is a miss: recomputed and rewritten
                    found[keys[key]] = vec
        return found

    def put_many(self, model_id: str, texts: list[str], vectors: np.ndarray) -> None:
        rows = [
            (embedding_key(model_id, t), model_id, int(v.shape[0]), _pack(v))
            for t, v in zip(texts, vectors)
        ]
        with self._errors(), self._db:
            self._db.executemany("INSERT OR REPLACE INTO embeddings VALUES (?, ?, ?, ?)", rows)

    def __len__(self) -> int:
        with self._errors():
            return self._db.execute("SELECT COUNT(*) FROM embeddings").fetchone()[0]

    def close(self) -> None:
        self._db.close()
