"""Durations as people write them ("500ms", "12s", "2m") and as the engine counts them.

The engine counts time in integer microseconds so that virtual runs are exact and repeatable:
no floating-point drift accumulates over a long run, and two runs give identical traces.
"""

from __future__ import annotations

import re

from hmi.limits import MAX_DURATION_US

US_PER = {"us": 1, "ms": 1_000, "s": 1_000_000, "m": 60_000_000, "min": 60_000_000,
          "h": 3_600_000_000}

# ASCII digits only: `\d` would take "１０ms" (fullwidth) or "٣s" for numbers, which an
# engineer reading the file would not see as the digits the engine counts.
DURATION_RE = re.compile(r"^[ \t]*([0-9]{1,15}(?:\.[0-9]{1,9})?)[ \t]*(us|ms|s|min|m|h)[ \t]*$")
DURATION_HINT = "a duration such as 500ms, 2s, 1.5s or 2m"


class DurationError(ValueError):
    """Not a duration, or one too long; `reason` says which, in the engineer's words."""

    def __init__(self, text: str, reason: str):
        super().__init__(f"{text!r} {reason}")
        self.reason = reason


def parse_duration(text: str) -> int:
    """Parse a duration into microseconds; raise DurationError with a readable reason."""
    match = DURATION_RE.match(text)
    if not match:
        raise DurationError(text, "is not a duration")
    number, unit = match.groups()
    us = _to_us(number, unit)
    if us > MAX_DURATION_US:
        raise DurationError(text, f"is longer than the longest duration allowed "
                            f"({MAX_DURATION_US // 3_600_000_000}h)")
    return us


def _to_us(number: str, unit: str) -> int:
    """Exact conversion: '1.5' and 's' give 1_500_000 without passing through a float."""
    whole, _, frac = number.partition(".")
    scale = US_PER[unit]
    value = int(whole) * scale
    if frac:
        value += int(frac) * scale // (10 ** len(frac))
    return value


def format_duration(us: int) -> str:
    """A compact human form: 2s, 500ms, 1.5s, 2m, 150us."""
    if us == 0:
        return "0s"
    if us % 60_000_000 == 0:
        return f"{us // 60_000_000}m"
    if us % 1_000_000 == 0:
        return f"{us // 1_000_000}s"
    if us >= 1_000_000:
        return f"{us / 1_000_000:g}s"
    if us % 1_000 == 0:
        return f"{us // 1_000}ms"
    if us >= 1_000:
        return f"{us / 1_000:g}ms"
    return f"{us}us"


def seconds(us: int) -> str:
    """Virtual time as seconds with millisecond resolution, for traces and logs."""
    return f"{us // 1_000_000}.{(us % 1_000_000) // 1_000:03d}"
