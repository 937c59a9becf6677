"""Driving the app headless in virtual time: waits on the app's own state, never on the wall
clock.

The soak (``plchmi soak``) drives the real app with these, and so do the pilot tests, the
snapshot tests and the screenshot script (tests/ui_harness.py adds what only they need), so
that all of them see the same app in the same states. With a
:class:`~hmi.ui.driver.VirtualDriver` nothing scans unless the caller says so, hence every
screen these helpers produce is exactly repeatable.

A wait never has a deadline in seconds (a loaded machine made such tests fail): it lets the
app process what it has queued — every widget's messages, the screen's pending layout and
repaint, the callbacks due after a refresh, running workers, animations — until nothing is
left (:func:`drain`), then looks. A condition still false on an idle app will never come true
(nothing scans by itself), so the wait fails at once, saying so. Textual's own
``Pilot.press`` sleeps at least 20 ms per key to guess idleness from CPU time; :func:`press`
posts the key and drains instead, which is exact and faster. This reads a few of Textual's
private attributes (message queues, the screen's update flags): Textual is pinned (8.2.8).
"""

from __future__ import annotations

import asyncio
import unicodedata
from collections.abc import Callable
from typing import Any

from textual import events
from textual.geometry import Offset
from textual.keys import REPLACED_KEYS, _character_to_key, _get_unicode_name_from_key
from textual.pilot import Pilot
from textual.worker import WorkerState

from hmi.ui.app import PlcHmiApp

MAX_ROUNDS = 10_000  # of message processing in one drain: only a guard against a loop
# Textual's pilot gives up waiting for the screen's messages after 30 s of wall clock; a
# process starved by a loaded machine (a niced 30-minute soak at load 15) got there
# without anything being wrong. This is only a guard against a hang.
SCREEN_HANG_GUARD_S = 600.0


class WaitTimeout(AssertionError):
    pass


def screen_pending(screen) -> bool:
    """The screen has a layout, a repaint or callbacks due at its next refresh."""
    return bool(screen._layout_required or screen._repaint_required or screen._dirty_widgets
                or screen._callbacks or screen._recompose_required)


def refresh_due(app) -> list:
    """The screens whose refresh timer would do something now (VirtualDriver.hold): the
    active one with anything pending; one shown under a dialog with a layout, a widget to
    repaint or callbacks due (its own refresh hands the repaint to the active screen, and
    leaves itself marked for one more: not counted, or this would never end); any other
    with callbacks due (its timer runs only those)."""
    current = app.screen
    shown = app._background_screens
    due = []
    for screen in app.screen_stack:
        if screen is current:
            pending = screen_pending(screen)
        elif screen in shown:
            pending = (screen._layout_required or screen._dirty_widgets
                       or screen._callbacks or screen._recompose_required)
        else:
            pending = screen._callbacks
        if pending:
            due.append(screen)
    return due


def messages_pending(app) -> str:
    """A node (on any screen of the stack, or the app) with messages or callbacks queued."""
    nodes = [app]
    for each in app.screen_stack:
        nodes.extend(each.walk_children(with_self=True))
    for node in nodes:
        if not node._message_queue.empty() or node._next_callbacks:
            return f"{node!r}: messages pending"
    return ""


def busy(app) -> str:
    """What the app has left to do that a test could be waiting for ('' if nothing)."""
    for screen in refresh_due(app):
        return f"{screen!r}: layout, repaint or callbacks pending"
    doing = messages_pending(app)
    if doing:
        return doing
    for worker in app.workers:
        if worker.state in (WorkerState.PENDING, WorkerState.RUNNING):
            return f"worker {worker.name!r} running"
    animator = app.animator
    if animator._animations or animator._scheduled:
        return f"animations {list(animator._animations) or list(animator._scheduled)}"
    return ""


async def drain(pilot: Pilot) -> None:
    """Let the app process everything it has queued, and lay out and repaint its screen."""
    app = pilot.app
    doing = ""
    for _ in range(MAX_ROUNDS):
        if app._exit or not app.is_running:
            return  # the app is ending: nothing more to wait for
        await pilot._wait_for_screen(timeout=SCREEN_HANG_GUARD_S)
        await asyncio.sleep(0)  # workers and tasks get their turn
        # Messages first: the screen is laid out and painted once they are all handled
        # (what its refresh timer would do, VirtualDriver.hold), so that one layout and one
        # paint serve them all, not one per round.
        doing = messages_pending(app)
        if doing:
            continue
        due = refresh_due(app)
        if due:
            for screen in due:
                screen._on_timer_update()
            continue
        doing = busy(app)
        if not doing:
            return
    raise WaitTimeout(f"the app was still busy after {MAX_ROUNDS} rounds: {doing}")


async def press(pilot: Pilot, *keys: str) -> None:
    """Press keys one after the other, each handled (and what it opened drawn) before the
    next; like ``Pilot.press`` without its CPU-idle sleeps."""
    app = pilot.app
    for key in keys:
        event = key_event(key)
        event.set_sender(app)
        app._driver.send_message(event)
        await drain(pilot)


def key_event(key: str) -> events.Key:
    """The event a terminal sends for `key`, built as ``Pilot.press`` builds it."""
    if len(key) == 1 and not key.isalnum():
        key = _character_to_key(key)
    try:
        char = unicodedata.lookup(_get_unicode_name_from_key(REPLACED_KEYS.get(key, key)))
    except KeyError:
        char = key if len(key) == 1 else None
    return events.Key(key, char)


async def click(pilot: Pilot, selector: str, x: int = 0, y: int = 0) -> bool:
    """A mouse click at (x, y) from a widget's top-left corner, as a terminal sends it (down,
    up, click), each handled before the next; like ``Pilot.click`` without its sleeps.
    False (nothing clicked) if the point is off the screen or the widget is not shown."""
    app = pilot.app
    screen = app.screen
    widget = screen.query_one(selector)
    if not widget.display or not widget.region:
        return False
    arguments = {"widget": widget, "delta_x": 0, "delta_y": 0, "button": 1, "shift": False,
                 "meta": False, "ctrl": False}
    point = widget.region.offset + Offset(x, y)
    if point not in screen.size.region:
        return False
    arguments.update(x=point.x, y=point.y, screen_x=point.x, screen_y=point.y)
    for cls in (events.MouseDown, events.MouseUp, events.Click):
        kwargs = {**arguments, "chain": 1} if cls is events.Click else arguments
        app.mouse_position = point
        screen._forward_event(cls(**kwargs))
        await drain(pilot)
    return True


async def settle(pilot: Pilot) -> None:
    """Hand the latest snapshot to the panels and let Textual process what is queued."""
    app = pilot.app
    assert isinstance(app, PlcHmiApp)
    app.poll(force=True)
    await drain(pilot)


async def wait_until(pilot: Pilot, predicate: Callable[[], Any], what: str = "condition"
                     ) -> Any:
    """Let the app work until `predicate()` is truthy; fail once the app is idle without it.

    For a live app (a scan thread), see :func:`wait_live`."""
    for _ in range(3):
        result = predicate()
        if result:
            return result
        await drain(pilot)
    result = predicate()
    if result:
        return result
    raise WaitTimeout(f"{what} did not happen: the app has nothing left to do")


async def wait_for_screen(pilot: Pilot, screen_type: type):
    """Wait until the active screen is a `screen_type` and return it (mounted)."""
    screen = await wait_until(
        pilot, lambda: isinstance(pilot.app.screen, screen_type) and pilot.app.screen,
        f"a {screen_type.__name__}")
    await drain(pilot)
    return screen


