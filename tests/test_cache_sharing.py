"""Runs in separate processes sharing one judge cache pay each request once (leases in the SQLite cache), and a
lease left by a killed process is taken over."""

import json
import os
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from simeval.devserver import LoopbackOpenAI
from simeval.judges.cache import CachedCall, JudgeCache
from simeval.judges.providers import Image

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def _png(seed: int) -> bytes:
    return Image.from_array(np.random.default_rng(seed).integers(0, 255, (16, 16, 3))).png


def make_bundles(root: Path, n: int) -> Path:
    for t in range(n):
        d = root / f"task{t}"
        (d / "scene").mkdir(parents=True)
        (d / "frames").mkdir()
        (d / "task.yaml").write_text(yaml.safe_dump({"description": f"stack block {t}", "pipeline": "gensim"}))
        for v in range(2):
            (d / "scene" / f"view{v}.png").write_bytes(_png(100 * t + v))
        for f in range(3):
            (d / "frames" / f"{f:04d}.png").write_bytes(_png(1000 * t + f))
    return root


def two_concurrent_runs(root: Path, tmp: Path, *, tasks: int = 3, repeats: int = 3, latency_s: float = 0.4,
                        src: Path = SRC) -> tuple[int, list[dict]]:
    """Start two quality.py processes at once on one cache; return (HTTP calls the server saw, result.json's)."""
    bundles = make_bundles(tmp / "b", tasks)
    with LoopbackOpenAI(latency_s=latency_s) as srv:
        common = [f"bundles_dir={bundles}", f"judge.provider.base_url={srv.base_url}", f"repeats={repeats}",
                  "judge.concurrency=2", f"cache_dir={tmp / 'cache'}"]
        env = {**os.environ, "PYTHONPATH": str(src)}
        procs = [subprocess.Popen([sys.executable, str(src / "quality.py"), *common, f"hydra.run.dir={tmp / f'r{i}'}"],
                                  cwd=root, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for i in range(2)]
        outs = [p.communicate(timeout=300) for p in procs]
        for p, (_, err) in zip(procs, outs):
            assert p.returncode == 0, err[-2000:]
        calls = len(srv.requests)
    return calls, [json.loads((tmp / f"r{i}" / "result.json").read_text()) for i in range(2)]


def test_two_concurrent_runs_pay_each_request_once(tmp_path):
    tasks, repeats = 3, 3
    distinct = tasks * 2 * repeats  # scene alignment + task completion, each repeated
    calls, results = two_concurrent_runs(ROOT, tmp_path, tasks=tasks, repeats=repeats)
    assert calls == distinct  # without leases both runs ask most requests: up to 2 x distinct
    assert sum(r["cost"]["new_calls"] for r in results) == distinct
    assert sum(r["cost"]["cached_calls"] for r in results) == distinct  # the other run's replies, waited for
    assert results[0]["values"] == results[1]["values"]
    # every lease ended with its reply: a row left behind would make a later run wait on it until it expires
    db = sqlite3.connect(tmp_path / "cache" / "judge_calls.sqlite")
    assert db.execute("SELECT key, owner, expires FROM leases").fetchall() == []


HOLDER = textwrap.dedent("""
    import sys, time
    from simeval.judges.cache import JudgeCache
    cache = JudgeCache(sys.argv[1])
    assert cache.claim("k") is None
    print("held", flush=True)
    time.sleep(float(sys.argv[2]))
    if sys.argv[3] == "put":
        from simeval.judges.cache import CachedCall
        cache.put(CachedCall("k", "Score: 5", 10, 2, 0, 0.5, 1.0, time.time()), provider="p", model="m", item="i",
                  metric="scene_alignment", repeat=0, ask=0)
    print("done", flush=True)
""")


def _holder(path: Path, seconds: float, then: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(path), str(seconds), then], text=True,
                            stdout=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(SRC)})
    assert proc.stdout.readline().strip() == "held"
    return proc


def _claim_in_thread(cache: JudgeCache) -> tuple[threading.Thread, list]:
    out: list = []
    t = threading.Thread(target=lambda: out.append(cache.claim("k")), daemon=True)
    t.start()
    return t, out


def test_a_waiting_run_gets_the_other_process_reply_without_asking(tmp_path):
    path = tmp_path / "c.sqlite"
    proc = _holder(path, 0.8, "put")
    cache = JudgeCache(path, max_poll_s=0.05)
    t0 = time.monotonic()
    hit = cache.claim("k")
    assert time.monotonic() - t0 > 0.3  # it waited for the holder's reply
    assert hit is not None and hit.reply == "Score: 5" and cache.waited == 1
    proc.wait(timeout=30)


def test_lease_of_a_killed_process_is_taken_over(tmp_path):
    path = tmp_path / "c.sqlite"
    proc = _holder(path, 600, "sleep")
    cache = JudgeCache(path, max_poll_s=0.05)
    t, out = _claim_in_thread(cache)
    time.sleep(0.5)
    assert t.is_alive()  # the holder is alive: wait, do not ask too
    proc.kill()
    proc.wait()
    t.join(timeout=10)
    assert not t.is_alive() and out == [None]  # None: this cache now holds the lease and asks the model
    owner = sqlite3.connect(path).execute("SELECT owner FROM leases WHERE key = 'k'").fetchone()[0]
    assert owner == cache.owner


def test_expired_lease_from_another_host_is_taken_over_and_a_live_one_waited_for(tmp_path):
    path = tmp_path / "c.sqlite"
    cache = JudgeCache(path, max_poll_s=0.05)
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("INSERT INTO leases VALUES ('k', 'elsewhere:1:x', 'elsewhere', 1, ?)", (time.time() + 600,))
    t, out = _claim_in_thread(cache)
    time.sleep(0.4)
    assert t.is_alive()  # a live lease on another machine is waited for (its pid cannot be checked from here)
    db.execute("UPDATE leases SET expires = ? WHERE key = 'k'", (time.time() - 1,))  # it stopped renewing
    t.join(timeout=10)
    assert out == [None]


def test_failed_call_releases_its_lease_and_a_stored_reply_ends_it(tmp_path):
    from simeval.judges.ledger import Ledger, Prices
    from simeval.judges.prompts import load_template
    from simeval.judges.providers import OpenAIChatProvider
    from simeval.judges.runner import JudgeItem, JudgeSettings, run_judge
    from simeval.httpretry import FatalHTTPError
    import pytest

    tpl = load_template("builtin:scene_alignment_vlm")
    items = [JudgeItem("t0", "scene_alignment", tpl, {"description": "d"}, [Image.from_png(_png(0))], (1, 5))]
    cache = JudgeCache(tmp_path / "c.sqlite")
    with LoopbackOpenAI() as srv:
        srv.faults.append({"status": 401, "message": "bad key"})
        provider = OpenAIChatProvider(base_url=srv.base_url, model="m", backoff_s=0.01)
        with pytest.raises(FatalHTTPError, match="bad key"):
            run_judge(items, provider, cache, Ledger(Prices()), JudgeSettings(repeats=1, progress=False))
        db = sqlite3.connect(tmp_path / "c.sqlite")
        assert db.execute("SELECT COUNT(*) FROM leases").fetchone()[0] == 0  # nobody waits on a failed call
        run_judge(items, provider, cache, Ledger(Prices()), JudgeSettings(repeats=2, progress=False))
        assert db.execute("SELECT COUNT(*) FROM leases").fetchone()[0] == 0 and len(cache) == 2


def test_put_stores_a_reply_other_caches_see(tmp_path):
    a, b = JudgeCache(tmp_path / "c.sqlite"), JudgeCache(tmp_path / "c.sqlite")
    assert a.claim("k") is None
    a.put(CachedCall("k", "Score: 2", 1, 1, 0, 0.0, 0.1, time.time()), provider="p", model="m", item="i",
          metric="x", repeat=0, ask=0)
    assert b.claim("k").reply == "Score: 2" and b.waited == 0



def test_a_cache_opens_while_another_process_is_creating_the_file(tmp_path):
    # Another run has just created the file and holds its write lock (here: for 0.4 s). Switching to WAL then
    # fails at once with "database is locked", without waiting; before use_wal retried, two runs started together
    # on a fresh cache_dir stopped with that error about one time in three (the CI failure of 2026-11-20).
    from simeval.embeddings.cache import EmbeddingCache

    for kind, cls in [("judge", JudgeCache), ("embedding", EmbeddingCache)]:
        path = tmp_path / f"{kind}.sqlite"
        other = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        other.execute("BEGIN IMMEDIATE")
        other.execute("CREATE TABLE IF NOT EXISTS creating (x)")
        threading.Timer(0.4, lambda db=other: db.execute("COMMIT")).start()
        t0 = time.monotonic()
        cls(path, timeout_s=10)
        assert 0.3 < time.monotonic() - t0 < 10  # it waited for the other writer instead of failing
        assert sqlite3.connect(path).execute("PRAGMA journal_mode").fetchone()[0] == "wal"
