"""A damaged (garbage or truncated) or locked SQLite cache stops with one line naming the file and what to do,
not a traceback from inside sqlite3."""

import os
import sqlite3
import time
from pathlib import Path

import numpy as np
import pytest

from simeval.embeddings.cache import EmbeddingCache
from simeval.errors import UserError
from simeval.judges.cache import CachedCall, JudgeCache

from helpers import _error_line, run_quality


def _call(key: str) -> CachedCall:
    return CachedCall(key, "Score: 3 " * 40, 100, 5, 1, 0.001, 0.1, time.time())


def _put(cache: JudgeCache, key: str) -> None:
    cache.put(_call(key), provider="openai", model="m", item="t", metric="scene_alignment", repeat=0, ask=0)


def _truncate(path: Path, fraction: float) -> None:
    with open(path, "r+b") as f:
        f.truncate(int(os.path.getsize(path) * fraction))


def test_garbage_judge_cache_names_the_file_and_says_it_holds_paid_replies(tmp_path):
    path = tmp_path / "judge_calls.sqlite"
    path.write_bytes(os.urandom(8192))
    with pytest.raises(UserError) as e:
        JudgeCache(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: the judge cache is damaged or not an SQLite file")
    assert "paid for" in msg and "move it aside" in msg and "judge_calls.sqlite-wal" in msg


def test_truncated_judge_cache(tmp_path):
    path = tmp_path / "judge_calls.sqlite"
    cache = JudgeCache(path)
    for i in range(300):
        _put(cache, f"k{i}")
    cache.close()
    _truncate(path, 0.5)
    with pytest.raises(UserError, match=f"^{path}: the judge cache is damaged"):
        cache = JudgeCache(path)
        cache.get("k299")
        len(cache)


def test_garbage_and_truncated_embedding_cache(tmp_path):
    path = tmp_path / "embeddings.sqlite"
    path.write_bytes(b"not a database " * 500)
    with pytest.raises(UserError, match=f"^{path}: the embedding cache is damaged.*delete it or move it aside"):
        EmbeddingCache(path)
    path.unlink()
    cache = EmbeddingCache(path)
    cache.put_many("m", [f"t{i}" for i in range(500)], np.ones((500, 32)))
    cache.close()
    _truncate(path, 0.3)
    with pytest.raises(UserError, match=f"^{path}: the embedding cache is damaged"):
        EmbeddingCache(path).get_many("m", ["t1", "t499"])


def test_locked_caches_stop_after_the_timeout_naming_the_file(tmp_path):
    jpath, epath = tmp_path / "j.sqlite", tmp_path / "e.sqlite"
    JudgeCache(jpath).close()
    EmbeddingCache(epath).close()
    holders = []
    for p in (jpath, epath):  # another program holding a write transaction open (e.g. a sqlite3 shell)
        db = sqlite3.connect(p, isolation_level=None)
        db.execute("BEGIN EXCLUSIVE")
        holders.append(db)
    judge = JudgeCache(jpath, timeout_s=0.3)
    assert judge.get("k") is None  # WAL: reading goes on while another process writes
    t0 = time.monotonic()
    with pytest.raises(UserError, match=f"^{jpath}: the judge cache is locked by another process \\(waited 0.3 s"):
        _put(judge, "k")
    assert time.monotonic() - t0 < 5
    with pytest.raises(UserError, match="lock"):
        judge.claim("k")
    with pytest.raises(UserError, match=f"^{epath}: the embedding cache is locked by another process"):
        EmbeddingCache(epath, timeout_s=0.3).put_many("m", ["a"], np.ones((1, 4)))
    holders[0].execute("ROLLBACK")
    _put(judge, "k")  # once the other writer lets go, the same cache works
    assert judge.get("k") is not None


def test_quality_with_a_garbage_judge_cache_is_one_line(openai_server, tmp_path):
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "judge_calls.sqlite").write_bytes(os.urandom(4096))
    line = _error_line(run_quality(tmp_path, f"judge.provider.base_url={openai_server.base_url}"))
    assert line.startswith(f"error: {tmp_path / 'cache' / 'judge_calls.sqlite'}: the judge cache is damaged")
    assert openai_server.requests == []
