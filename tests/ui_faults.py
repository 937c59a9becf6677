"""A test-only hook: deliberate UI errors, to prove fault containment on the real program.

``PLCHMI_TEST_UI_FAULT`` set in the environment (tests only; nothing happens when it is
unset) makes the HMI fail on purpose once the engine's time reaches an instant:

- ``panel`` or ``panel@2s``: the constraints panel raises at every frame from then on — the
  error must be contained (banner, journal), the scan and the other panels go on;
- ``fatal`` or ``fatal@2s``: an error reaches Textual itself (a timer's callback: Textual
  hands its errors straight to its last resort, no handler of ours in between), which ends
  the app — it must end as an abnormal end (safe outputs on a real plant, a journal
  entry with the reason, exit status 1).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from hmi.timefmt import parse_duration

ENV = "PLCHMI_TEST_UI_FAULT"
KINDS = ("panel", "fatal")


class DeliberateUIError(RuntimeError):
    """Raised by the hook; its message says so, in the crash file and the journal."""


@dataclass(frozen=True)
class TestFault:
    kind: str  # one of KINDS
    after_us: int = 0


def from_environment() -> TestFault | None:
    text = os.environ.get(ENV, "").strip()
    if not text:
        return None
    kind, _, when = text.partition("@")
    if kind not in KINDS:
        raise ValueError(f"{ENV}={text!r}: expected {' or '.join(KINDS)}, optionally @TIME")
    return TestFault(kind, parse_duration(when) if when else 0)


class Armed:
    """The hook installed in one app; `tick` is called with each frame's time."""

    def __init__(self, app, fault: TestFault):
        self.app = app
        self.fault = fault
        self.fired = False
        if fault.kind == "panel":
            from hmi.ui.constraints_panel import ConstraintsPanel
            panel = app.query_one(ConstraintsPanel)
            show = panel.show

            def failing_show(frame) -> None:
                if frame.snapshot.time_us >= fault.after_us:
                    raise DeliberateUIError(f"{ENV}: deliberate error in the constraints "
                                            "panel")
                show(frame)
            panel.show = failing_show  # type: ignore[method-assign]

    def tick(self, time_us: int) -> None:
        if self.fault.kind != "fatal" or self.fired or time_us < self.fault.after_us:
            return
        self.fired = True

        def fail() -> None:
            raise DeliberateUIError(f"{ENV}: deliberate error outside any handler")
        self.app.set_timer(0.001, fail)
