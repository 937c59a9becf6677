"""Lengths of history and instants, as an operator writes them on the command line.

A length: ``90d``, ``2h``, ``30min``, ``45s``, ``1.5h``, ``2w`` (weeks). An instant: a
length back from now (``--since 2h``), or a date and time in ISO 8601 (``2026-11-18T03:12``,
``2026-11-18 03:12:05``; the machine's local time unless it says its zone, ``...Z`` or
``+01:00``), or ``now``.
"""

from __future__ import annotations

import re
from datetime import datetime

US_PER = {"s": 1_000_000, "min": 60_000_000, "m": 60_000_000, "h": 3_600_000_000,
          "d": 86_400_000_000, "w": 7 * 86_400_000_000}
SPAN_RE = re.compile(r"^\s*([0-9]{1,9}(?:\.[0-9]{1,6})?)\s*(s|min|m|h|d|w)\s*$")
SPAN_HINT = "a length such as 90d, 2h, 30min or 45s"
INSTANT_HINT = f"{SPAN_HINT} (back from now), a date and time such as 2026-11-18T03:12, or now"
MAX_SPAN_US = 100 * 365 * 86_400_000_000


class SpanError(ValueError):
    """Not a length or an instant; the message says what was expected."""


def parse_span(text: str) -> int:
    """A length in microseconds (more than zero)."""
    match = SPAN_RE.match(text)
    if not match:
        raise SpanError(f"{text!r} is not a length (expected {SPAN_HINT})")
    number, unit = match.groups()
    whole, _, frac = number.partition(".")
    us = int(whole) * US_PER[unit]
    if frac:
        us += int(frac) * US_PER[unit] // 10 ** len(frac)
    if us <= 0:
        raise SpanError(f"{text!r}: the length must be more than zero")
    if us > MAX_SPAN_US:
        raise SpanError(f"{text!r} is longer than a hundred years")
    return us


def parse_instant(text: str, now_us: int) -> int:
    """An instant in microseconds since the epoch: `now_us` minus a length, a date and
    time, or now."""
    if text.strip().lower() == "now":
        return now_us
    if SPAN_RE.match(text):
        return now_us - parse_span(text)
    try:
        if not text.isascii():  # digits a reader would not see as such
            raise ValueError(text)
        when = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise SpanError(f"{text!r} is not an instant (expected {INSTANT_HINT})") from None
    if when.tzinfo is None:
        when = when.astimezone()  # the machine's local time
    return round(when.timestamp() * 1_000_000)
