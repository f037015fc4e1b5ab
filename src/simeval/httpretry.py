"""POST JSON to an HTTP API with bounded retries: 429 and 5xx (honouring Retry-After / retry-after-ms), timeouts and
broken connections are retried with exponential backoff; other 4xx stop at once with the server's message, and so
does a connection that cannot be opened at all (refused, or a host name that does not resolve: a server that is not
running or a mistyped base_url, which waiting does not fix) (a `FatalHTTPError`, which entrypoints print as one line).
Every attempt is recorded so callers can report them. Also: where an API key may be sent (`check_key_transport`),
how it is read (`api_key_from_env`), and that a remote endpoint has one (`require_key_for_remote`).

Why not the official `openai` client (it was pinned but never imported; the pin is gone):
- Its retries are internal. It retries the same statuses (408/409/429/5xx, connection errors) and honours
  Retry-After, but only up to 2 retries by default, caps its own backoff at 8 s, and gives up at once when a server
  asks to wait longer than its ceiling; the attempts are not returned, so we could record each retry in a ledger
  only by parsing its debug log or hooking its transport. Here every attempt (status, error, latency, wait) is
  returned to the caller.
- We talk to servers that are not OpenAI (vLLM, Ollama, LM Studio, TEI, and the fault-injecting loopback server
  of the tests): two JSON routes (`/chat/completions`, `/embeddings`) and Azure's deployment URL + `api-key`
  header are all we use, and a plain `httpx.Client` with a per-request timeout does them in ~100 lines we can test
  against every fault.
- Weight: it pulls pydantic, pydantic-core, jiter, anyio, distro and its own httpx fork (~40 MB) into every
  install, for typed response models we would not use.
Revisit if we need streaming, the Responses/Batch APIs, or OAuth/Entra ID token refresh for Azure."""

from __future__ import annotations

import email.utils
import ipaddress
import os
import random
import re
import time
from dataclasses import dataclass
from typing import Any

import httpx

from simeval.errors import UserError
from simeval.secrets import key_shape

RETRYABLE_STATUS = frozenset({408, 409, 425, 429, 500, 502, 503, 504})


class FatalHTTPError(UserError, RuntimeError):
    """A reply that retrying will not fix (401, 403, 400, 404, ...), or retries exhausted. A UserError, so an
    entrypoint prints its one-line message (URL, status, the server's own message) and exits 2: a bad key, model
    name or request parameter is for the user to fix, and an endpoint down after every retry is for them to see."""

    def __init__(self, message: str, status: int | None = None, attempts: list | None = None) -> None:
        super().__init__(message)
        self.status, self.attempts = status, attempts or []


@dataclass
class RetryPolicy:
    max_retries: int = 5
    backoff_s: float = 1.0  # first wait; doubles each retry
    max_backoff_s: float = 60.0
    jitter: float = 0.1  # fraction of the wait added at random, so concurrent clients do not retry in lockstep

    def __post_init__(self) -> None:
        if self.max_retries < 0 or self.backoff_s < 0:
            raise ValueError(f"retry: max_retries and backoff_s must be >= 0, got {self.max_retries}, {self.backoff_s}")

    def wait(self, attempt: int, retry_after: float | None) -> float:
        base = min(self.max_backoff_s, self.backoff_s * 2**attempt)
        if retry_after is not None:
            base = max(base, min(retry_after, self.max_backoff_s))
        return base * (1 + self.jitter * random.random())


@dataclass
class Attempt:
    status: int | None
    error: str | None
    latency_s: float
    waited_s: float = 0.0


def retry_after_from(headers) -> float | None:
    """Seconds a 429/503 asks us to wait: `retry-after-ms` (OpenAI, Azure) first, then `Retry-After`."""
    ms = headers.get("retry-after-ms")
    if ms:
        try:
            return max(0.0, float(ms) / 1000)
        except ValueError:
            pass
    return parse_retry_after(headers.get("retry-after"))


def parse_retry_after(value: str | None) -> float | None:
    """Seconds to wait from a Retry-After header (delta-seconds or an HTTP date); None if absent or unparseable,
    in which case the normal backoff applies."""
    if not value:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    return max(0.0, when.timestamp() - time.time())


def _short(text: str, limit: int = 300) -> str:
    text = " ".join(text.split())  # one line: error bodies are often pretty-printed JSON or HTML
    return text if len(text) <= limit else text[:limit] + "..."


def server_message(resp: httpx.Response) -> str:
    """The server's own error text on one line: `error.message` of an OpenAI-style body, else the body."""
    try:
        body = resp.json()
    except ValueError:
        body = None
    if isinstance(body, dict):
        err = body.get("error", body)
        msg = err.get("message") if isinstance(err, dict) else err
        if isinstance(msg, str) and msg.strip():
            return _short(msg)
        if isinstance(body.get("detail"), str):  # FastAPI-style servers (vLLM, TEI)
            return _short(body["detail"])
    return _short(resp.text) or "(empty body)"


def is_loopback_url(url: str) -> bool:
    """True for http(s) URLs whose host is this machine: localhost (and *.localhost), 127.0.0.0/8, ::1."""
    host = (httpx.URL(url).host or "").lower().rstrip(".")
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_key_transport(base_url: str, *, config_key: str, key_env: str, allow_insecure_http: bool) -> None:
    """Refuse to send an API key in clear text: over plain http it is allowed only to this machine (a local vLLM
    or Ollama) unless `<config_key>.allow_insecure_http=true`."""
    try:
        url = httpx.URL(base_url)
    except (httpx.InvalidURL, TypeError) as e:
        raise UserError(f"{config_key}.base_url={base_url!r} is not a URL ({e}); expected e.g. "
                        "https://api.openai.com/v1 or http://127.0.0.1:8000/v1") from None
    if url.scheme not in ("http", "https") or not url.host:
        raise UserError(f"{config_key}.base_url={base_url!r}: expected an http:// or https:// URL with a host")
    if url.scheme == "http" and not allow_insecure_http and not is_loopback_url(base_url):
        raise UserError(
            f"{config_key}.base_url={base_url}: refusing to send the API key from ${key_env} over plain http to "
            f"another host, where anyone on the network path can read it; use https, or unset {key_env} (or "
            f"{config_key}.api_key_env=null) for a server without auth, or set {config_key}.allow_insecure_http=true "
            "to send it anyway")


_ENV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def api_key_from_env(api_key_env: str | None, *, config_key: str) -> str | None:
    """The key in the environment variable named `api_key_env` (None if unnamed or unset). A *value* given where
    the name belongs is refused without echoing it: it would sit in the config, the saved `.hydra/` files and logs."""
    if api_key_env is None or api_key_env == "":
        return None
    if not isinstance(api_key_env, str):
        raise UserError(f"{config_key}.api_key_env must be the name of an environment variable, got a "
                        f"{type(api_key_env).__name__}")
    why = key_shape(api_key_env)
    if why:
        raise UserError(f"{config_key}.api_key_env holds what looks like the key itself ({why}), not the name of "
                        f"an environment variable; remove it from your config (and rotate the key if the config "
                        f"was shared), export it (e.g. OPENAI_API_KEY=...) and set {config_key}.api_key_env="
                        "OPENAI_API_KEY")
    if not _ENV_NAME.match(api_key_env):
        raise UserError(f"{config_key}.api_key_env must be the name of an environment variable (letters, digits, "
                        f"underscores, e.g. OPENAI_API_KEY); got a value of {len(api_key_env)} characters that is "
                        "not one")
    return os.environ.get(api_key_env) or None


def require_key_for_remote(key: str | None, base_url: str, *, config_key: str, key_env: str | None) -> None:
    """A named key variable that is unset, for an endpoint on another machine (api.openai.com, Azure, a remote
    vLLM), is a mistake to say before the first request: unauthenticated requests only come back as 401s, or,
    offline, as a connection error that never mentions the key. Loopback servers (a local vLLM or Ollama) need no
    key, and `<config_key>.api_key_env=null` says a remote one needs none either."""
    if key or not key_env or is_loopback_url(base_url):
        return
    raise UserError(f"{config_key}: the environment variable {key_env} (named by {config_key}.api_key_env) is not set, "
                    f"and {base_url} is not on this machine; export {key_env}=<your key>, or set "
                    f"{config_key}.api_key_env=null for a server without auth")


def post_json(
    client: httpx.Client,
    url: str,
    payload: dict,
    *,
    headers: dict | None = None,
    retry: RetryPolicy | None = None,
    timeout_s: float | None = None,
    sleep=time.sleep,
) -> tuple[Any, list[Attempt]]:
    """Return (decoded JSON body, attempts). Raises FatalHTTPError when the call cannot succeed."""
    retry = retry or RetryPolicy()
    attempts: list[Attempt] = []
    for attempt in range(retry.max_retries + 1):
        t0 = time.perf_counter()
        retry_after = None
        try:
            resp = client.post(url, json=payload, headers=headers, timeout=timeout_s)
        except httpx.ConnectError as e:  # nothing listens there, or the name does not resolve: not transient
            attempts.append(Attempt(None, f"{type(e).__name__}: {e}", time.perf_counter() - t0))
            raise FatalHTTPError(f"POST {url}: cannot connect ({e}); is the server running, and is base_url right?",
                                 None, attempts) from None
        except (httpx.TimeoutException, httpx.TransportError) as e:
            attempts.append(Attempt(None, f"{type(e).__name__}: {e}", time.perf_counter() - t0))
        else:
            latency = time.perf_counter() - t0
            if resp.status_code < 300:
                try:
                    body = resp.json()
                except ValueError as e:
                    attempts.append(Attempt(resp.status_code, f"invalid JSON body: {e}", latency))
                else:
                    attempts.append(Attempt(resp.status_code, None, latency))
                    return body, attempts
            elif resp.status_code in RETRYABLE_STATUS:
                retry_after = retry_after_from(resp.headers)
                attempts.append(Attempt(resp.status_code, server_message(resp), latency))
            else:
                message = server_message(resp)
                attempts.append(Attempt(resp.status_code, message, latency))
                hint = " (check the API key in the environment variable named by api_key_env)" \
                    if resp.status_code in (401, 403) else ""
                raise FatalHTTPError(f"POST {url} -> HTTP {resp.status_code}{hint}: {message}", resp.status_code,
                                     attempts)
        if attempt < retry.max_retries:
            wait = retry.wait(attempt, retry_after)
            attempts[-1].waited_s = wait
            sleep(wait)
    last = attempts[-1]
    what = f"HTTP {last.status}: {last.error}" if last.status is not None else last.error
    raise FatalHTTPError(f"POST {url} failed after {len(attempts)} attempts (max_retries={retry.max_retries}); "
                         f"last: {what}", last.status, attempts)
