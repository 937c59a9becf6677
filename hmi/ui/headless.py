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
posts the key and drains instead, which is exact and faster. What this needs of Textual's
insides (a screen's pending refresh, a node's next callbacks, handing a mouse event to a
widget) is in hmi/ui/textual_adapter.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
import unicodedata
from collections.abc import Callable
from typing import Any, TypeVar

from textual import events
from textual.app import App
from textual.geometry import Offset
from textual.keys import ASCII_KEY_NAMES, KEY_NAME_REPLACEMENTS, REPLACED_KEYS, key_to_character
from textual.message_pump import MessagePump
from textual.pilot import Pilot
from textual.screen import Screen
from textual.worker import WorkerState

from hmi.ui.app import PlcHmiApp
from hmi.ui.textual_adapter import forward_mouse_event, next_callbacks_due, refresh, refresh_due

S = TypeVar("S", bound=Screen[Any])

MAX_ROUNDS = 10_000  # of message processing in one drain: only a guard against a loop
# Textual's pilot gives up waiting for the screen's messages after 30 s of wall clock; a
# process starved by a loaded machine (a niced 30-minute soak at load 15) got there
# without anything being wrong. This is only a guard against a hang.
SCREEN_HANG_GUARD_S = 600.0


class WaitTimeout(AssertionError):
    pass


def messages_pending(app: App[Any]) -> str:
    """A node (on any screen of the stack, or the app) with messages or callbacks queued."""
    nodes: list[MessagePump] = [app]
    for each in app.screen_stack:
        nodes.extend(each.walk_children(with_self=True))
    for node in nodes:
        if node.message_queue_size or next_callbacks_due(node):
            return f"{node!r}: messages pending"
    return ""


def busy(app: App[Any]) -> str:
    """What the app has left to do that a test could be waiting for ('' if nothing)."""
    for screen in refresh_due(app):
        return f"{screen!r}: layout, repaint or callbacks pending"
    doing = messages_pending(app)
    if doing:
        return doing
    for worker in app.workers:
        if worker.state in (WorkerState.PENDING, WorkerState.RUNNING):
            return f"worker {worker.name!r} running"
    return ""


def ending(app: App[Any]) -> bool:
    """The app was told to exit (it has a return code), or is no longer running."""
    return app.return_code is not None or not app.is_running


async def handled(app: App[Any]) -> None:
    """Until the app and every node of its active screen have handled what was queued to
    them before now (a callback queued behind it on each, ``call_later``), or the app ends.
    The wall clock only notices an app that ended meanwhile (its nodes answer no more), and
    a hang."""
    done = asyncio.Event()
    count = 0

    def one_less() -> None:
        nonlocal count
        count -= 1
        if count == 0:
            done.set()

    for node in (app, *app.screen.walk_children(with_self=True)):
        if node.call_later(one_less):
            count += 1
    started = time.monotonic()
    while count and not done.is_set():
        if ending(app):
            return
        if time.monotonic() - started > SCREEN_HANG_GUARD_S:
            raise WaitTimeout(f"the app's nodes did not answer in {SCREEN_HANG_GUARD_S:g} s")
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(done.wait(), timeout=0.1)


async def drain(pilot: Pilot[Any]) -> None:
    """Let the app process everything it has queued, and lay out and repaint its screen."""
    app = pilot.app
    doing = ""
    for _ in range(MAX_ROUNDS):
        if ending(app):
            return  # the app is ending: nothing more to wait for
        await handled(app)
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
                refresh(screen)
            continue
        doing = busy(app)
        if not doing:
            await app.animator.wait_until_complete()  # none runs in virtual time, as a rule
            if not busy(app):
                return
        elif running_workers(app):
            await workers_move(app)
    raise WaitTimeout(f"the app was still busy after {MAX_ROUNDS} rounds: {doing}")


def running_workers(app: App[Any]) -> list[Any]:
    return [w for w in app.workers if w.state in (WorkerState.PENDING, WorkerState.RUNNING)]


async def workers_move(app: App[Any]) -> None:
    """Until a worker ends or posts to the app (a thread reading a database takes the
    machine's time, not the app's: counting rounds meanwhile gave up after 10,000 of them
    on a loaded machine, in a soak farm's replay). Wall clock only as a guard against a
    hang."""
    started = time.monotonic()
    count = len(running_workers(app))
    while len(running_workers(app)) == count and not messages_pending(app) \
            and not refresh_due(app) and not ending(app):
        if time.monotonic() - started > SCREEN_HANG_GUARD_S:
            raise WaitTimeout(f"a worker ran for {SCREEN_HANG_GUARD_S:g} s: "
                              f"{[w.name for w in running_workers(app)]}")
        await asyncio.sleep(0.002)


async def press(pilot: Pilot[Any], *keys: str) -> None:
    """Press keys one after the other, each handled (and what it opened drawn) before the
    next; like ``Pilot.press`` without its CPU-idle sleeps."""
    app = pilot.app
    for key in keys:
        event = key_event(key)
        event.set_sender(app)
        app.post_message(event)
        await drain(pilot)


def key_event(key: str) -> events.Key:
    """The event a terminal sends for `key`, as ``Pilot.press`` builds it: a printable
    character that is not a letter or digit goes by its Unicode name (``+`` is ``plus``)."""
    if len(key) == 1 and not key.isalnum():
        try:
            name = unicodedata.name(key).lower().replace("-", "_").replace(" ", "_")
        except ValueError:  # a control character
            name = ASCII_KEY_NAMES.get(key, key)
        key = KEY_NAME_REPLACEMENTS.get(name, name)
    return events.Key(key, key_to_character(REPLACED_KEYS.get(key, key)))


async def click(pilot: Pilot[Any], selector: str, x: int = 0, y: int = 0) -> bool:
    """A mouse click at (x, y) from a widget's top-left corner, as a terminal sends it (down,
    up, click), each handled before the next; like ``Pilot.click`` without its sleeps.
    False (nothing clicked) if the point is off the screen or the widget is not shown."""
    app = pilot.app
    screen = app.screen
    widget = screen.query_one(selector)
    if not widget.display or not widget.region:
        return False
    point = widget.region.offset + Offset(x, y)
    if not screen.size.region.contains_point(point):
        return False
    kinds: tuple[type[events.MouseEvent], ...] = (events.MouseDown, events.MouseUp, events.Click)
    for cls in kinds:  # button 1, no modifier; a click's chain is 1 (a single click)
        app.mouse_position = point
        forward_mouse_event(screen, cls(widget, point.x, point.y, 0, 0, 1, False, False, False,
                                        screen_x=point.x, screen_y=point.y))
        await drain(pilot)
    return True


async def settle(pilot: Pilot[Any]) -> None:
    """Hand the latest snapshot to the panels and let Textual process what is queued."""
    app = pilot.app
    assert isinstance(app, PlcHmiApp)
    app.poll(force=True)
    await drain(pilot)


async def wait_until(pilot: Pilot[Any], predicate: Callable[[], Any], what: str = "condition"
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


async def wait_for_screen(pilot: Pilot[Any], screen_type: type[S]) -> S:
    """Wait until the active screen is a `screen_type` and return it (mounted)."""
    def shown() -> S | None:
        screen = pilot.app.screen
        return screen if isinstance(screen, screen_type) else None
    screen = await wait_until(pilot, shown, f"a {screen_type.__name__}")
    await drain(pilot)
    assert isinstance(screen, screen_type)
    return screen


