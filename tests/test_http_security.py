"""Where an API key may go, and how HTTP faults end: a key never travels over plain http to another host unless
the user says so, a key given where its variable's name belongs stops the run without being echoed, and 401/400
end `src/quality.py` with one line carrying the server's message (exit 2, no traceback)."""

import os
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
import yaml

from simeval.embeddings.remote import OpenAIEmbeddingBackend
from simeval.errors import UserError
from simeval.httpretry import FatalHTTPError, RetryPolicy, is_loopback_url, post_json
from simeval.judges.providers import OpenAIChatProvider

ROOT = Path(__file__).resolve().parents[1]
from helpers import FAKE_KEY, _bundles, _error_line, run_quality  # noqa: E402


def _recording_transport(seen: list) -> httpx.MockTransport:
    """Stands in for a server on another host (no such host is reachable from a test): records what it gets."""
    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return httpx.Response(200, json={"choices": [{"message": {"content": "Score: 3"}}],
                                         "usage": {"prompt_tokens": 1, "completion_tokens": 1}})
    return httpx.MockTransport(handler)


def _provider(base_url: str, seen: list, **kw) -> OpenAIChatProvider:
    p = OpenAIChatProvider(base_url=base_url, model="m", max_retries=0, **kw)
    p._client = httpx.Client(transport=_recording_transport(seen))
    return p


@pytest.mark.parametrize("url,loopback", [
    ("http://127.0.0.1:8000/v1", True), ("http://127.3.2.1/v1", True), ("http://localhost:11434/v1", True),
    ("http://[::1]:8000/v1", True), ("http://10.0.0.5:8000/v1", False), ("http://judge.example.com/v1", False),
    ("http://localhost.example.com/v1", False), ("http://127.0.0.1.nip.io/v1", False),
])
def test_loopback_hosts(url, loopback):
    assert is_loopback_url(url) is loopback


def test_key_is_not_sent_over_plain_http_to_another_host(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    seen: list = []
    p = _provider("http://judge.example.com/v1", seen)
    with pytest.raises(UserError) as e:
        p.complete("s", "u", [])
    assert seen == []  # refused before anything left the machine
    msg = str(e.value)
    assert msg.startswith("judge.provider.base_url=http://judge.example.com/v1: refusing to send the API key")
    assert "judge.provider.allow_insecure_http=true" in msg and FAKE_KEY not in msg and "\n" not in msg


def test_key_goes_over_https_to_loopback_or_with_the_override(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    for url, kw in [("https://judge.example.com/v1", {}), ("http://127.0.0.1:8000/v1", {}),
                    ("http://judge.example.com/v1", {"allow_insecure_http": True})]:
        seen: list = []
        assert _provider(url, seen, **kw).complete("s", "u", []).text == "Score: 3"
        assert seen[0].headers["authorization"] == f"Bearer {FAKE_KEY}", url


def test_no_key_no_refusal_and_azure_header_is_covered_too(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    seen: list = []
    # a server without auth (api_key_env=null): plain http is fine, there is nothing secret to leak
    _provider("http://judge.example.com/v1", seen, api_key_env=None).complete("s", "u", [])
    assert "authorization" not in seen[0].headers
    monkeypatch.setenv("AZURE_OPENAI_API_KEY", "0123456789abcdef0123456789abcdef")
    p = _provider("http://NAME.openai.azure.com", seen, api_style="azure", api_version="2024-02-15-preview",
                  api_key_env="AZURE_OPENAI_API_KEY", config_key="captioner.provider")
    with pytest.raises(UserError, match=r"captioner.provider.allow_insecure_http=true"):
        p.complete("s", "u", [])


def test_embedding_backend_refuses_plain_http_to_another_host(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    backend = OpenAIEmbeddingBackend("http://embed.invalid/v1", "m", max_retries=0, timeout_s=1)
    with pytest.raises(UserError, match=r"embedding.backend.allow_insecure_http=true") as e:
        backend.embed(["a"])
    assert FAKE_KEY not in str(e.value)


def test_embedding_backend_sends_the_key_to_loopback(monkeypatch, openai_server):
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    OpenAIEmbeddingBackend(openai_server.base_url, "m").embed(["a"])
    assert openai_server.requests[0]["headers"]["Authorization"] == f"Bearer {FAKE_KEY}"


@pytest.mark.parametrize("env_name", [FAKE_KEY, "Bearer abcdefghijklmnop", "hf_abcdefghijklmnopqrstuvwxyz"])
def test_a_key_given_as_the_variable_name_stops_without_echoing_it(env_name, openai_server):
    p = OpenAIChatProvider(base_url=openai_server.base_url, model="m", api_key_env=env_name)
    with pytest.raises(UserError, match="api_key_env holds what looks like the key itself") as e:
        p.complete("s", "u", [])
    assert env_name not in str(e.value) and env_name.split()[-1] not in str(e.value)
    assert openai_server.requests == []
    with pytest.raises(UserError, match="embedding.backend.api_key_env holds what looks like the key"):
        OpenAIEmbeddingBackend(openai_server.base_url, "m", api_key_env=env_name).embed(["a"])


def test_retry_after_ms_is_honoured(openai_server):
    openai_server.faults.append({"status": 429, "headers": {"retry-after-ms": "300"}})
    waits: list = []
    with httpx.Client() as c:
        _, attempts = post_json(c, openai_server.base_url + "/embeddings", {"model": "m", "input": ["a"]},
                                retry=RetryPolicy(backoff_s=0.001, jitter=0.0), sleep=waits.append)
    assert [a.status for a in attempts] == [429, 200] and waits == [pytest.approx(0.3)]


def test_fatal_http_error_is_one_line_with_the_server_message(openai_server):
    openai_server.faults.append({"status": 400, "message": "Invalid value for 'model':\n  'gpt-5o' does not exist"})
    with httpx.Client() as c, pytest.raises(FatalHTTPError) as e:
        post_json(c, openai_server.base_url + "/chat/completions", {})
    assert isinstance(e.value, UserError) and "\n" not in str(e.value)
    assert str(e.value).endswith("HTTP 400: Invalid value for 'model': 'gpt-5o' does not exist")


# --- through the entrypoint -------------------------------------------------------------------------------------

@pytest.mark.parametrize("status,message", [(401, "Incorrect API key provided: sk-abc***"),
                                            (400, "Invalid model 'gpt-5o'")])
def test_quality_stops_on_401_400_with_one_line(status, message, openai_server, tmp_path):
    openai_server.faults.extend([{"status": status, "message": message}] * 20)
    line = _error_line(run_quality(tmp_path, f"judge.provider.base_url={openai_server.base_url}"))
    assert f"-> HTTP {status}" in line and line.endswith(message)


def test_quality_refuses_plain_http_to_another_host(tmp_path):
    line = _error_line(run_quality(tmp_path, "judge.provider.base_url=http://judge.invalid/v1",
                                   "judge.provider.max_retries=0"))
    assert line.startswith("error: judge.provider.base_url=http://judge.invalid/v1: refusing to send the API key")
    assert FAKE_KEY not in line


def test_quality_stops_on_a_key_in_a_config_file(openai_server, tmp_path):
    conf = tmp_path / "myconf" / "judge"
    conf.mkdir(parents=True)
    (conf / "mine.yaml").write_text(yaml.safe_dump({"defaults": ["openai", "_self_"],
                                                    "provider": {"api_key_env": FAKE_KEY}}))
    res = run_quality(tmp_path, "judge=mine", f"judge.provider.base_url={openai_server.base_url}",
                      flags=(f"--config-dir={tmp_path / 'myconf'}",))
    line = _error_line(res)
    # stopped by the entrypoint's config check, before the provider is even built
    assert "judge.provider.api_key_env holds what looks like a secret" in line
    assert FAKE_KEY not in res.stderr + res.stdout and openai_server.requests == []
    # what the run wrote (the user's own config file holds the key; the refused run's folder is removed)
    saved = [p for p in tmp_path.rglob("*") if p.is_file() and "myconf" not in p.parts]
    assert not any(FAKE_KEY in p.read_text(errors="replace") for p in saved)


def test_a_remote_endpoint_without_its_key_stops_before_any_request(monkeypatch):
    """No key for api.openai.com (or any host not on this machine): one line naming the variable, nothing sent;
    offline this used to end ~35 s later in a DNS error that never mentioned the key."""
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    seen: list = []
    with pytest.raises(UserError) as e:
        _provider("https://api.openai.com/v1", seen).complete("s", "u", [])
    assert seen == [] and "\n" not in str(e.value)
    assert str(e.value).startswith("judge.provider: the environment variable OPENAI_API_KEY (named by "
                                   "judge.provider.api_key_env) is not set")
    assert "judge.provider.api_key_env=null" in str(e.value)
    # a local server needs no key, and api_key_env=null says a remote one needs none
    assert _provider("http://127.0.0.1:8000/v1", seen).complete("s", "u", []).text == "Score: 3"
    assert _provider("https://judge.example.com/v1", seen, api_key_env=None).complete("s", "u", []).text == "Score: 3"
    assert [r.headers.get("authorization") for r in seen] == [None, None]
    backend = OpenAIEmbeddingBackend(base_url="https://api.openai.com/v1", model="text-embedding-3-small")
    with pytest.raises(UserError, match="^embedding.backend: the environment variable OPENAI_API_KEY"):
        backend.embed(["a task"])


def test_a_refused_connection_is_not_retried():
    """Nothing listens on the port: one attempt and a line that says so, not ~35 s of backoff."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed when the block ends: nothing listens there
    waits: list = []
    with pytest.raises(FatalHTTPError) as e:
        post_json(httpx.Client(), f"http://127.0.0.1:{port}/v1/chat/completions", {}, retry=RetryPolicy(5, 1.0),
                  sleep=waits.append)
    assert waits == [] and len(e.value.attempts) == 1
    assert str(e.value).startswith(f"POST http://127.0.0.1:{port}/v1/chat/completions: cannot connect (")
    assert str(e.value).endswith("is the server running, and is base_url right?")


def test_quality_without_the_key_for_a_remote_judge_is_one_line(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "OPENAI_API_KEY"}
    res = subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), f"bundles_dir={_bundles(tmp_path / 'b')}",
                          f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}", "repeats=1",
                          "judge=openai", "judge.provider.base_url=https://api.openai.com/v1"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    line = _error_line(res)
    assert "OPENAI_API_KEY (named by judge.provider.api_key_env) is not set" in line
