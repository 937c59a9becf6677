"""Who runs the scans while the app is open.

- :class:`LiveDriver`: the real thing. A :class:`~hmi.session.live.LiveRunner` thread paces the
  scans by the wall clock; the UI only reads ``session.last`` and never waits for a scan.
- :class:`VirtualDriver`: for tests and screenshots. Nothing runs by itself; the test calls
  :meth:`VirtualDriver.advance` to run scans in virtual time, exactly as the live runner
  would have (none while paused), so what the screen shows is repeatable to the character.
"""

from __future__ import annotations

import gc
import sys
from functools import partial

from textual.screen import Screen

from hmi.session.live import LiveRunner
from hmi.session.session import Session

# The scan thread and the UI share one interpreter lock. When the scan thread wakes up for
# its next scan while the UI is rendering, it waits until the UI thread is asked to let go,
# by default after 5 ms: that would be most of a 10 ms period. Half a millisecond bounds
# that wait; measured by `plchmi bench ui`.
SWITCH_INTERVAL_S = 0.0005


class LiveDriver:
    live = True

    def __init__(self, controller: Session):
        self.controller = controller
        self.runner = LiveRunner(controller)

    def start(self) -> None:
        """Start scanning. Called once the app is mounted, so that its widgets exist."""
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        # LiveRunner.start freezes what exists (the app's widgets included) out of the
        # garbage collector's sight: a full collection over them took ~40 ms here.
        self.runner.start()
        # The start (hmi.cli.ui) runs without automatic collection, to here: the scans run
        # with it, as every other session does.
        gc.enable()

    def stop(self) -> None:
        self.runner.stop()

    @property
    def overruns(self) -> int:
        return self.runner.overruns

    @property
    def error(self) -> BaseException | None:
        """Why the scan thread died (None while it runs or after a normal stop)."""
        return self.runner.error


class _Held:
    """A screen's refresh timer that never fires: see :meth:`VirtualDriver.hold`."""

    def pause(self) -> None:
        pass

    def resume(self) -> None:
        pass


HELD = _Held()
MOST_DIRTY = 64  # regions kept to repaint; beyond, the whole screen's region instead


def _unseen_refresh(screen) -> None:
    """``Screen._compositor_refresh`` without the paint, for a headless screen: what is to be
    repainted is kept for :meth:`VirtualDriver.paint`; the rest is Textual's (the screen
    under a dialog passes its changes up, the mouse-over is updated)."""
    app = screen.app
    if screen is app.screen:
        screen._dirty_widgets.clear()
        dirty = screen._compositor._dirty_regions
        if len(dirty) > MOST_DIRTY:
            dirty.clear()
            dirty.add(screen._compositor.size.region)
        app._update_mouse_over(screen)
    else:
        Screen._compositor_refresh(screen)


class VirtualDriver:
    live = False
    overruns = 0
    error = None

    @staticmethod
    def hold(screen) -> None:
        """The screen lays out and paints when whoever drives virtual time says so
        (hmi.ui.testing.drain: once everything queued is handled), never on its refresh
        timer: that timer fires 1/60 s of wall clock after a change, so on a loaded machine
        it painted half-handled states a second time, and what ran depended on the load.
        Textual's ``Screen._update_timer`` (pause/resume, created at first use) is the one
        thing it paces by the clock; this sets it before then (Textual pinned, 8.2.8).

        Headless (tests, the soak, screenshots), a layout does not paint either: a headless
        terminal throws every paint away, and whoever looks renders the screen then
        (hmi.ui.testing.screen_text, ``App.export_screenshot``), or the line it needs (a
        click's style, ``Widget.render_lines``), or what changed (:meth:`paint`). Painting
        each frame nobody could see was about a third of a pilot test's CPU, and more under
        a dialog (the screen below it re-tinted at each paint)."""
        screen._Screen__update_timer = HELD
        if screen.app.is_headless:
            screen._compositor_refresh = partial(_unseen_refresh, screen)

    @staticmethod
    def paint(app) -> bool:
        """Paint what changed on the active screen since it was last painted, as its refresh
        would have on a terminal; True if there was anything. For whoever wants every state
        drawn that it stops at (the soak, after each step: a widget that fails to draw fails
        there); a test that looks at the screen renders it whole anyway."""
        screen = app.screen
        compositor = screen._compositor
        if app.driver.live or not app.is_headless or not compositor._dirty_regions:
            return False
        compositor.render_update(screen_stack=app._background_screens)
        return True

    def __init__(self, controller: Session):
        self.controller = controller

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def advance(self, duration_us: int) -> int:
        """Run the scans that `duration_us` of virtual time holds, if running; return how many."""
        controller = self.controller
        if not controller.state.running:
            return 0
        end = controller.engine.now + duration_us
        count = 0
        while controller.state.running and controller.next_time <= end:
            controller.scan_once()
            count += 1
        return count

    def advance_until(self, predicate, limit_us: int) -> bool:
        """Run scans until `predicate(snapshot)` holds, at most `limit_us` of virtual time."""
        controller = self.controller
        end = controller.engine.now + limit_us
        while controller.state.running and controller.next_time <= end:
            if predicate(controller.scan_once()):
                return True
        return False
