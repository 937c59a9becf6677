"""Who runs the scans while the app is open, and who shows their frames.

- :class:`LiveDriver`: the real thing. The link's scans (a runtime process, or a
  :class:`~hmi.session.live.LiveRunner` thread in this process) are paced by the wall clock;
  the UI reads the link's latest view at most 20 times a second and never waits for a scan.
- :class:`VirtualDriver`: for tests, screenshots and the soak. Nothing runs by itself; the
  caller calls :meth:`VirtualDriver.advance` to run scans in virtual time, exactly as the
  live runner would have (none while paused), so what the screen shows is repeatable to the
  character.
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hmi.link.base import CellLink
from hmi.ui.textual_adapter import hold_refresh, paint_changes, paint_later

if TYPE_CHECKING:
    from textual.screen import Screen


class LiveDriver:
    live = True

    def __init__(self, link: CellLink):
        self.link = link

    @property
    def runner(self) -> Any:
        """The scan thread, when the scans run in this process (the single-process bench)."""
        return getattr(self.link, "runner", None)

    def start(self) -> None:
        """Start scanning. Called once the app is mounted, so that its widgets exist."""
        self.link.start()
        # The start (hmi.cli.ui) runs without automatic collection, to here: the screen runs
        # with it, as every other process does.
        gc.enable()

    def stop(self) -> None:
        self.link.stop()

    @property
    def overruns(self) -> int:
        view = self.link.view()
        return view.overruns if view is not None else 0

    @property
    def error(self) -> BaseException | None:
        """Why the scans stopped on their own (None while they run or after a normal stop)."""
        return self.link.error


class VirtualDriver:
    live = False
    overruns = 0
    error = None

    @staticmethod
    def hold(screen: Screen[Any]) -> None:
        """The screen lays out and paints when whoever drives virtual time says so
        (hmi.ui.headless.drain: once everything queued is handled), never on its refresh
        timer: that timer fires 1/60 s of wall clock after a change, so on a loaded machine
        it painted half-handled states a second time, and what ran depended on the load.
        Textual's ``Screen._update_timer`` (pause/resume, created at first use) is the one
        thing it paces by the clock; this holds it before then (hmi/ui/textual_adapter.py).

        Headless (tests, the soak, screenshots), a layout does not paint either: a headless
        terminal throws every paint away, and whoever looks renders the screen then
        (tests/ui_harness.py's screen_text, ``App.export_screenshot``), or the line it needs (a
        click's style, ``Widget.render_lines``), or what changed (:meth:`paint`). Painting
        each frame nobody could see was about a third of a pilot test's CPU, and more under
        a dialog (the screen below it re-tinted at each paint)."""
        hold_refresh(screen)
        if screen.app.is_headless:
            paint_later(screen)

    @staticmethod
    def paint(app: Any) -> bool:  # a PlcHmiApp (hmi.ui.app imports this module)
        """Paint what changed on the active screen since it was last painted, as its refresh
        would have on a terminal; True if there was anything. For whoever wants every state
        drawn that it stops at (the soak, after each step: a widget that fails to draw fails
        there); a test that looks at the screen renders it whole anyway."""
        if app.driver.live or not app.is_headless:
            return False
        return paint_changes(app)

    def __init__(self, link: CellLink):
        self.link = link

    def start(self) -> None:
        pass

    def stop(self) -> None:
        self.link.stop()

    def advance(self, duration_us: int) -> int:
        """Run the scans that `duration_us` of virtual time holds, if running; return how many."""
        return self.link.advance(duration_us)

    def advance_until(self, predicate: Callable[[Any], bool], limit_us: int) -> bool:
        """Run scans until `predicate(snapshot)` holds, at most `limit_us` of virtual time."""
        return self.link.advance_until(predicate, limit_us)
