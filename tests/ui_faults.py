"""Deliberate UI errors, to prove fault containment on the real program (tests only).

:func:`inject` makes every PlcHmiApp started afterwards in the test fail on purpose once the
engine's time reaches an instant, as the text says:

- ``panel`` or ``panel@2s``: the constraints panel raises at every frame from then on — the
  error must be contained (banner, journal), the scan and the other panels go on;
- ``fatal`` or ``fatal@2s``: an error reaches Textual itself (a timer's callback: Textual
  hands its errors straight to its last resort, no handler of ours in between), which ends
  the app — it must end as an abnormal end (safe outputs on a real plant, a journal
  entry with the reason, exit status 1).

The app itself knows nothing of this: the test wraps its frame refresh (``PlcHmiApp.poll``)
with pytest's monkeypatch, which undoes it at the end of the test.
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from hmi.timefmt import parse_duration
from hmi.ui.app import PlcHmiApp
from hmi.ui.constraints_panel import ConstraintsPanel

KINDS = ("panel", "fatal")


class DeliberateUIError(RuntimeError):
    """Raised by the hook; its message says so, in the crash file and the journal."""


@dataclass(frozen=True)
class TestFault:
    kind: str  # one of KINDS
    after_us: int = 0


def parse(text: str) -> TestFault:
    """`panel`, `fatal`, optionally `@TIME` (`fatal@1.5s`)."""
    kind, _, when = text.strip().partition("@")
    if kind not in KINDS:
        raise ValueError(f"{text!r}: expected {' or '.join(KINDS)}, optionally @TIME")
    return TestFault(kind, parse_duration(when) if when else 0)


class Armed:
    """The fault installed in one app; `tick` is called with each frame's time."""

    def __init__(self, app: PlcHmiApp, fault: TestFault):
        self.app = app
        self.fault = fault
        self.fired = False
        if fault.kind == "panel":
            panel = app.query_one(ConstraintsPanel)
            show = panel.show

            def failing_show(frame) -> None:
                if frame.snapshot.time_us >= fault.after_us:
                    raise DeliberateUIError("deliberate error in the constraints panel")
                show(frame)
            panel.show = failing_show  # type: ignore[method-assign]

    def tick(self, time_us: int) -> None:
        if self.fault.kind != "fatal" or self.fired or time_us < self.fault.after_us:
            return
        self.fired = True

        def fail() -> None:
            raise DeliberateUIError("deliberate error outside any handler")
        self.app.set_timer(0.001, fail)


def inject(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    """Arm `text`'s fault in every PlcHmiApp of this test, at its first frame."""
    fault = parse(text)
    poll = PlcHmiApp.poll
    armed: dict[int, Armed] = {}

    def poll_and_fail(app: PlcHmiApp, force: bool = False) -> bool:
        hook = armed.get(id(app))
        if hook is None or hook.app is not app:
            hook = armed[id(app)] = Armed(app, fault)
        shown = poll(app, force)
        if shown:
            hook.tick(app.frame.snapshot.time_us)
        return shown

    monkeypatch.setattr(PlcHmiApp, "poll", poll_and_fail)
