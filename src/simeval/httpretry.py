"""POST JSON to an HTTP API with bounded retries: 429 and 5xx (honouring Retry-After) and timeouts/connection
errors are retried with exponential backoff; other 4xx stop at once with the server's message. Every attempt is
recorded so callers can report them."""

from __future__ import annotations

import email.utils
import random
import time
from dataclasses import dataclass
from typing import Any

import httpx

RETRYABLE_STATUS = frozenset({408, 409, 425, 429, 500, 502, 503, 504})


class FatalHTTPError(RuntimeError):
    """A reply that retrying will not fix (401, 403, 400, 404, ...), or retries exhausted."""

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
    return text if len(text) <= limit else text[:limit] + "..."


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
                retry_after = parse_retry_after(resp.headers.get("retry-after"))
                attempts.append(Attempt(resp.status_code, _short(resp.text), latency))
            else:
                attempts.append(Attempt(resp.status_code, _short(resp.text), latency))
                hint = " (check the API key environment variable)" if resp.status_code in (401, 403) else ""
                raise FatalHTTPError(
                    f"POST {url} -> HTTP {resp.status_code}{hint}: {_short(resp.text)}", resp.status_code, attempts
                )
        if attempt < retry.max_retries:
            wait = retry.wait(attempt, retry_after)
            attempts[-1].waited_s = wait
            sleep(wait)
    last = attempts[-1]
    raise FatalHTTPError(
        f"POST {url} failed after {len(attempts)} attempts; last: HTTP {last.status} {last.error}", last.status, attempts
    )
