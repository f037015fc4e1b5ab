"""Run a judge over items: repeats, re-asks on invalid replies, concurrency, a rate limiter, the cache, the
ledger (cost and budget), dry runs and replay-only runs."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

from simeval.judges.cache import CachedCall, JudgeCache, request_key
from simeval.judges.ledger import BudgetExceeded, Ledger
from simeval.judges.parse import parse_score
from simeval.judges.prompts import PromptTemplate
from simeval.judges.providers import Image
from simeval.errors import UserError, require_whole


class ReplayMiss(UserError, RuntimeError):
    """A replay-only run met a request that is not in the cache (a UserError: the entrypoint prints one line)."""


@dataclass
class JudgeItem:
    item_id: str
    metric: str
    template: PromptTemplate
    fields: dict
    images: list[Image]
    scale: tuple[float, float] | None  # None: a free-text reply (a caption); any non-empty text is valid
    pipeline: str | None = None  # for the cost ledger's per metric/pipeline totals

    @property
    def cost_label(self) -> str:
        return f"{self.metric}/{self.pipeline or 'unknown'}"

    def rendered(self) -> tuple[str, str]:
        return self.template.render(n_images=str(len(self.images)), **self.fields)


@dataclass
class JudgeSettings:
    repeats: int = 5
    max_reasks: int = 2
    concurrency: int = 4
    rate_limit_per_min: float | None = None
    replay: bool = False
    progress: bool = True

    def __post_init__(self) -> None:
        require_whole("repeats", self.repeats)
        require_whole("max_reasks", self.max_reasks, 0)
        require_whole("judge.concurrency (or captioner.concurrency)", self.concurrency)
        rate = self.rate_limit_per_min
        if rate is not None and (isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0):
            raise UserError(f"judge.rate_limit_per_min (or captioner.rate_limit_per_min) must be a number > 0 or "
                            f"null (no limit), got {rate!r}")


class RateLimiter:
    """Spaces request starts at least 60/per_min seconds apart, across threads."""

    def __init__(self, per_min: float | None) -> None:
        self.interval = 60.0 / per_min if per_min else 0.0
        self._next = 0.0
        self._lock = threading.Lock()

    def acquire(self) -> None:
        if not self.interval:
            return
        with self._lock:
            now = time.monotonic()
            start = max(now, self._next)
            self._next = start + self.interval
        if start > now:
            time.sleep(start - now)


@dataclass
class ScoreRecord:
    item: str
    metric: str
    repeat: int
    provider: str
    model: str
    template_sha256: str
    image_sha256: list[str]
    asks: list[dict] = field(default_factory=list)
    score: float | None = None
    text: str | None = None  # the accepted reply of a free-text item

    @property
    def valid(self) -> bool:
        return self.score is not None or self.text is not None


def _accept(item: JudgeItem, reply: str | None) -> tuple[float | str | None, str | None]:
    """(value, error): a score on the item's scale, or for a free-text item (a caption) the stripped text."""
    if item.scale is None:
        text = (reply or "").strip()
        return (text, None) if text else (None, "empty reply")
    parsed = parse_score(reply, *item.scale)
    return parsed.value, parsed.error


def _estimate(ledger: Ledger, provider, item: JudgeItem, system: str, user: str) -> float:
    decoding = provider.decoding  # the output cap is called max_tokens (HTTP) or max_new_tokens (transformers)
    max_out = decoding.get("max_tokens") or decoding.get("max_new_tokens") or 64
    return ledger.prices.estimate(len(system) + len(user), len(item.images), max_out)


def _identity(provider, item: JudgeItem, system: str, user: str, repeat: int, ask: int) -> str:
    return request_key(provider=provider.name, endpoint=getattr(provider, "endpoint", ""), model=provider.model,
                       template_sha256=item.template.sha256,
                       system=system, user=user, image_sha256=[im.sha256 for im in item.images],
                       decoding=provider.decoding, repeat=repeat, ask=ask)


def dry_run(items: Sequence[JudgeItem], provider, cache: JudgeCache, ledger: Ledger, settings: JudgeSettings) -> dict:
    """What a run would do: calls not yet cached (first asks; re-asks cannot be known), images, estimated USD."""
    calls = images = cached = 0
    est = 0.0
    for item in items:
        system, user = item.rendered()
        for r in range(settings.repeats):
            if cache.get(_identity(provider, item, system, user, r, 0)):
                cached += 1
                continue
            calls += 1
            images += len(item.images)
            est += _estimate(ledger, provider, item, system, user)
    return {"calls": calls, "cached": cached, "images": images, "estimated_usd": round(est, 4),
            "note": "first asks only; each unparseable reply adds a re-ask (at most max_reasks per repeat)"}


@dataclass
class _Reply:
    text: str | None
    latency_s: float
    cached: bool
    retries: list
    cost_usd: float | None  # of a paid call; None for a cached one


@dataclass
class _Asker:
    """What one ask needs: the provider, the cache and ledger it pays through, and the rate limit."""
    provider: Any
    cache: JudgeCache
    ledger: Ledger
    settings: JudgeSettings
    limiter: RateLimiter

    def ask(self, item: JudgeItem, system: str, user: str, repeat: int, ask: int) -> _Reply:
        """The reply to one ask: from the cache, or paid for (reserved against the budget first) and cached."""
        provider, cache, ledger = self.provider, self.cache, self.ledger
        key = _identity(provider, item, system, user, repeat, ask)
        # claim: a miss leaves this run holding the key's lease until put()/release(); a request another
        # process is asking right now is waited for, not paid twice
        hit = cache.get(key) if self.settings.replay else cache.claim(key)
        if hit is not None:
            ledger.record_cached(hit.cost_usd, item.cost_label)
            return _Reply(hit.reply, hit.latency_s, True, [], None)
        if self.settings.replay:
            raise ReplayMiss(f"judge=replay: no cached reply for item '{item.item_id}' metric {item.metric} "
                             f"repeat {repeat} ask {ask} (endpoint {getattr(provider, 'endpoint', '') or '-'}, "
                             f"model {provider.model}, template {item.template.sha256[:12]}: all three are part "
                             "of the cache key, so give the live run's judge.provider.base_url and model); run "
                             "once with a live judge first")
        estimate = _estimate(ledger, provider, item, system, user)
        try:
            ledger.reserve(estimate)
        except BaseException:
            cache.release(key)
            raise
        try:
            self.limiter.acquire()
            out = provider.complete(system, user, item.images)
        except BaseException:
            ledger.release(estimate)
            cache.release(key)
            raise
        cost = ledger.settle(estimate, out.prompt_tokens, out.completion_tokens, len(item.images),
                             item.cost_label, retries=len(out.retries))
        cache.put(CachedCall(key, out.text, out.prompt_tokens, out.completion_tokens, len(item.images), cost,
                             out.latency_s, time.time()), provider=provider.name, model=provider.model,
                  item=item.item_id, metric=item.metric, repeat=repeat, ask=ask)
        return _Reply(out.text, out.latency_s, False, out.retries, cost)

    def judge(self, item: JudgeItem, repeat: int, stop: threading.Event) -> ScoreRecord | None:
        """One repeat of an item: asks until a reply parses or max_reasks re-asks are spent (None once stopped)."""
        provider = self.provider
        system, user = item.rendered()
        rec = ScoreRecord(item.item_id, item.metric, repeat, provider.name, provider.model, item.template.sha256,
                          [im.sha256 for im in item.images])
        for ask in range(self.settings.max_reasks + 1):
            if stop.is_set():
                return None
            reply = self.ask(item, system, user, repeat, ask)
            value, error = _accept(item, reply.text)
            if value is None and not reply.cached:  # a paid reply that gave nothing: the summary counts these
                self.ledger.record_invalid(reply.cost_usd, item.cost_label)
            rec.asks.append({"ask": ask, "reply": reply.text, "valid": value is not None, "error": error,
                             "latency_s": round(reply.latency_s, 4), "cached": reply.cached,
                             "retries": reply.retries})
            if isinstance(value, str):
                rec.text = value
            elif value is not None:
                rec.score = value
            if value is not None:
                break
        return rec


def run_judge(items: Sequence[JudgeItem], provider, cache: JudgeCache, ledger: Ledger,
              settings: JudgeSettings) -> list[ScoreRecord]:
    """Judge every item `repeats` times. Returns records in (item, repeat) order. Stops at the first error that
    will not heal (HTTP 401/400, budget, replay miss) after the calls in flight finish; what finished is cached."""
    asker = _Asker(provider, cache, ledger, settings, RateLimiter(settings.rate_limit_per_min))
    stop = threading.Event()
    slots = [(i, r) for i in range(len(items)) for r in range(settings.repeats)]
    records: list[ScoreRecord | None] = [None] * len(slots)

    def one(slot: int) -> None:
        if stop.is_set():
            return
        try:
            i, repeat = slots[slot]
            records[slot] = asker.judge(items[i], repeat, stop)
        except BaseException:
            stop.set()  # set here, not by the caller: the pool would otherwise start the next queued slot first
            raise

    progress = None
    if settings.progress:
        from tqdm import tqdm

        progress = tqdm(total=len(slots), desc=f"judging ({provider.model})", unit="call", leave=False)
    with ThreadPoolExecutor(max_workers=settings.concurrency) as pool:
        futures = [pool.submit(one, s) for s in range(len(slots))]
        if progress:
            for f in futures:
                f.add_done_callback(lambda _: progress.update(1))
        done, pending = wait(futures, return_when=FIRST_EXCEPTION)
        failed = next((f for f in done if f.exception() is not None), None)
        if failed is not None:
            stop.set()
            for f in pending:
                f.cancel()
            wait(futures)
    if progress:
        progress.close()
    if failed is not None:
        exc = failed.exception()
        if isinstance(exc, (BudgetExceeded, ReplayMiss)):
            exc.partial = [r for r in records if r is not None]  # type: ignore[attr-defined]
        raise exc
    return [r for r in records if r is not None]
