"""Cost of judge calls: tokens from each response's `usage`, images counted per call, priced from a table in
the judge config (USD per million input/output tokens, per image). Thread-safe; a budget is enforced by
reserving each call's estimated cost before it is sent."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from simeval.errors import UserError


class BudgetExceeded(UserError, RuntimeError):
    """The run reached budget_usd; what finished is cached and in result.json (status "stopped"). A UserError so
    the entrypoint prints one line: raising budget_usd and re-running continues where it stopped."""


@dataclass
class Prices:
    input_per_1m: float = 0.0
    output_per_1m: float = 0.0
    per_image: float = 0.0  # for providers that bill images apart from tokens
    image_tokens: int = 765  # for estimates only: tokens one image adds to the prompt (OpenAI, 512x512 tile)

    def __post_init__(self) -> None:
        for name in ("input_per_1m", "output_per_1m", "per_image", "image_tokens"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
                raise UserError(f"judge.prices.{name} must be a number >= 0, got {value!r}")

    def cost(self, prompt_tokens: int, completion_tokens: int, images: int) -> float:
        return (prompt_tokens * self.input_per_1m + completion_tokens * self.output_per_1m) / 1e6 \
            + images * self.per_image

    def estimate(self, prompt_chars: int, images: int, max_tokens: int) -> float:
        return self.cost(prompt_chars // 4 + images * self.image_tokens, max_tokens, images)


@dataclass
class Ledger:
    prices: Prices
    budget_usd: float | None = None
    new_calls: int = 0
    cached_calls: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0
    images: int = 0
    cost_usd: float = 0.0  # spent by this run
    cached_cost_usd: float = 0.0  # what the cached replies cost when they were bought
    invalid_calls: int = 0  # new calls whose reply held no valid score: paid for nothing
    invalid_cost_usd: float = 0.0
    retries: int = 0  # failed HTTP attempts (429, 5xx, timeouts) retried before a reply arrived
    reserved_usd: float = 0.0
    by_label: dict = field(default_factory=dict)  # "metric/pipeline" -> the same counters, for result.json
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        b = self.budget_usd
        if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float)) or not b >= 0):
            raise UserError(f"budget_usd must be a number of US dollars >= 0 or null (no budget), got {b!r}")

    def _bucket(self, label: str | None) -> dict:
        return self.by_label.setdefault(label or "unlabelled", {
            "new_calls": 0, "cached_calls": 0, "prompt_tokens": 0, "completion_tokens": 0, "images": 0,
            "cost_usd": 0.0, "cached_cost_usd": 0.0, "invalid_calls": 0, "invalid_cost_usd": 0.0,
            "retries": 0})

    def reserve(self, estimate: float) -> None:
        with self._lock:
            if self.budget_usd is not None and self.cost_usd + self.reserved_usd + estimate > self.budget_usd:
                raise BudgetExceeded(
                    f"budget_usd={self.budget_usd:g} would be exceeded: spent {self.cost_usd:.4f}, in flight "
                    f"{self.reserved_usd:.4f}, next call ~{estimate:.4f}")
            self.reserved_usd += estimate

    def settle(self, estimate: float, prompt_tokens: int, completion_tokens: int, images: int,
               label: str | None = None, retries: int = 0) -> float:
        cost = self.prices.cost(prompt_tokens, completion_tokens, images)
        with self._lock:
            self.reserved_usd -= estimate
            self._add(label, new_calls=1, prompt_tokens=prompt_tokens, completion_tokens=completion_tokens,
                      images=images, cost_usd=cost, retries=retries)
        return cost

    def _add(self, label: str | None, **deltas: float) -> None:
        """Add to the run's totals and to the metric/pipeline bucket (caller holds the lock)."""
        bucket = self._bucket(label)
        for key, delta in deltas.items():
            setattr(self, key, getattr(self, key) + delta)
            bucket[key] += delta

    def release(self, estimate: float) -> None:
        with self._lock:
            self.reserved_usd -= estimate

    def record_cached(self, cost: float, label: str | None = None) -> None:
        with self._lock:
            self._add(label, cached_calls=1, cached_cost_usd=cost)

    def record_invalid(self, cost: float, label: str | None = None) -> None:
        """A new (paid) call whose reply was unparseable or out of range: counted as paid for nothing."""
        with self._lock:
            self._add(label, invalid_calls=1, invalid_cost_usd=cost)

    def totals(self) -> dict:
        return {"new_calls": self.new_calls, "cached_calls": self.cached_calls, "prompt_tokens": self.prompt_tokens,
                "completion_tokens": self.completion_tokens, "images": self.images,
                "cost_usd": round(self.cost_usd, 6), "cached_cost_usd": round(self.cached_cost_usd, 6),
                "invalid_calls": self.invalid_calls, "invalid_cost_usd": round(self.invalid_cost_usd, 6),
                "retries": self.retries, "budget_usd": self.budget_usd,
                "by_metric_pipeline": {k: {**v, "cost_usd": round(v["cost_usd"], 6),
                                           "cached_cost_usd": round(v["cached_cost_usd"], 6),
                                           "invalid_cost_usd": round(v["invalid_cost_usd"], 6)}
                                       for k, v in sorted(self.by_label.items())}}
