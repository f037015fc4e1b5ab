"""Scores from judge replies. `Score: X` (any case, optional markdown, `=` or `:`) is looked for, the last
occurrence winning (judges often restate the format before answering); a reply that is only a number is accepted.
Anything else, or a number outside the scale, is invalid: it is recorded with its reason, never turned into a
number."""

from __future__ import annotations

import re
from dataclasses import dataclass

_SCORE = re.compile(r"score\W{0,6}?\s*[:=]\s*\**\s*(-?\d+(?:\.\d+)?)(?:\s*/\s*\d+)?", re.IGNORECASE)
_BARE = re.compile(r"^\s*\**\s*(-?\d+(?:\.\d+)?)\s*\**\s*\.?\s*$")


@dataclass(frozen=True)
class ParsedScore:
    value: float | None
    error: str | None

    @property
    def valid(self) -> bool:
        return self.value is not None


def parse_score(reply: str | None, low: float, high: float) -> ParsedScore:
    if reply is None or not reply.strip():
        return ParsedScore(None, "empty reply")
    matches = _SCORE.findall(reply)
    if not matches:
        bare = _BARE.match(reply)
        if not bare:
            return ParsedScore(None, "no 'Score: X' in reply")
        matches = [bare.group(1)]
    value = float(matches[-1])
    if not low <= value <= high:
        return ParsedScore(None, f"score {value:g} outside [{low:g}, {high:g}]")
    return ParsedScore(value, None)
