"""A fault to inject into a simulated plant, as written on the command line: `F5@12s`.

Plain data, so that commands (hmi.engine.commands), scenarios and the UI can carry one
without importing the simulated device models.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from hmi.errors import UsageError
from hmi.timefmt import DURATION_HINT, format_duration, parse_duration


@dataclass(frozen=True)
class Injection:
    """A fault to inject: `F5@12s`, `V1.F5@12s`, or with a duration `stop@3s+2s`."""

    code: str
    at_us: int
    device: str | None = None
    duration_us: int | None = None

    def __str__(self) -> str:
        prefix = f"{self.device}." if self.device else ""
        text = f"{prefix}{self.code}@{format_duration(self.at_us)}"
        if self.duration_us is not None:
            text += f"+{format_duration(self.duration_us)}"
        return text


_INJECT_RE = re.compile(r"^(?:(?P<device>[A-Za-z_]\w*)\.)?(?P<code>[A-Za-z_]\w*)"
                        r"@(?P<at>[^+]+)(?:\+(?P<dur>.+))?$")


def parse_injection(text: str) -> Injection:
    match = _INJECT_RE.match(text.strip())
    if not match:
        raise UsageError(f"--inject {text!r}: expected FAULT@TIME, DEVICE.FAULT@TIME or "
                         f"FAULT@TIME+DURATION, e.g. F5@12s")
    try:
        at = parse_duration(match["at"])
        duration = parse_duration(match["dur"]) if match["dur"] else None
    except ValueError:
        raise UsageError(f"--inject {text!r}: the time is not {DURATION_HINT}") from None
    return Injection(match["code"], at, match["device"], duration)


