"""The HMI as a screen of a runtime in another process (SocketLink), under Textual's pilot:
two HMIs on one cell see each other's acknowledgements and who is in control; an HMI whose
runtime is killed says RUNTIME LOST at once and never shows the last values as live; quitting
asks whether to stop the cell. The runtime runs in virtual time, driven by the screen in
control: what each screen shows is exact."""

from __future__ import annotations

import asyncio
import concurrent.futures
import signal
import threading

from ui_harness import palette, region_text, screen_text, wait_for_main

from hmi.explain.alarms import ACTIVE_ACK, ACTIVE_UNACK
from hmi.link.base import Identity
from hmi.link.client import SocketLink
from hmi.project.kept import fingerprint, load_once
from hmi.ui.app import PlcHmiApp
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.headless import drain, press, settle, wait_for_screen
from tests.conftest import PROJECTS
from tests.runtimes import RuntimeProcess, wait_for

VALVE = PROJECTS / "cispi_valve"
SIZE = (120, 36)


def screen(cell: RuntimeProcess, user: str, want_control: bool = True,
           role: str = "operator") -> PlcHmiApp:
    link = SocketLink(load_once(VALVE), cell.socket, fingerprint(VALVE, None),
                      Identity(user, role, "terminal", user), want_control)
    assert link.first_frame.wait(120)
    return PlcHmiApp(link, live=False, show_measured=False)


class Elsewhere:
    """An HMI in a thread of its own, with its own event loop (Textual's active app is one per
    loop and task context): a second operator's screen beside the test's. `do` runs a pilot
    step there, in the task that runs the app (its context), and returns its result."""

    def __init__(self, app: PlcHmiApp, size: tuple[int, int] = SIZE):
        self.app = app
        self.size = size
        self.ready = threading.Event()
        self.loop: asyncio.AbstractEventLoop | None = None
        self._steps: asyncio.Queue | None = None
        self.thread = threading.Thread(target=asyncio.run, args=(self._main(),), daemon=True)
        self.thread.start()
        assert self.ready.wait(300), "the second screen did not start"

    async def _main(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._steps = asyncio.Queue()
        async with self.app.run_test(size=self.size) as pilot:
            self.ready.set()
            while True:
                item = await self._steps.get()
                if item is None:
                    return
                step, args, done = item
                try:
                    done.set_result(await step(pilot, *args))
                except BaseException as exc:
                    done.set_exception(exc)

    def do(self, step, *args):
        assert self.loop is not None and self._steps is not None
        done: concurrent.futures.Future = concurrent.futures.Future()
        self.loop.call_soon_threadsafe(self._steps.put_nowait, (step, args, done))
        return done.result(300)

    def close(self) -> None:
        if self.loop is not None and self._steps is not None:
            self.loop.call_soon_threadsafe(self._steps.put_nowait, None)
        self.thread.join(300)


async def caught_up(pilot, app: PlcHmiApp, scan: int) -> None:
    """Until this screen's frames show `scan` (pushed by the runtime: a wait on state)."""
    wait_for(lambda: app.link.last.snapshot.scan >= scan,
             f"scan {scan} on {app.link.identity.user}")
    await settle(pilot)


async def test_two_hmis_see_the_alarm_the_other_acknowledged_and_who_is_in_control(tmp_path):
    sock = tmp_path / "data" / "two" / "runtime.sock"
    cell = RuntimeProcess(VALVE, sock, "--control", "faulty")
    bob_screen = None
    try:
        alice = screen(cell, "alice")
        bob = screen(cell, "bob", want_control=False)
        async with alice.run_test(size=SIZE) as pa:
            bob_screen = Elsewhere(bob)
            alice.driver.advance(8_000_000)
            await settle(pa)
            scan = alice.link.last.snapshot.scan
            bob_screen.do(caught_up, bob, scan)
            first = next(a for a in alice.link.last.alarms if a.state == ACTIVE_UNACK)
            assert "▲ UNACK" in region_text(bob, "#alarms")
            assert "● in control" in region_text(alice, "#status")
            assert "control: alice (terminal, c1)" in region_text(bob, "#status")
            # bob's acknowledgement is refused (not in control), and said
            bob_screen.do(press, "A")
            assert "REFUSED" in region_text(bob, "#message")
            assert "not in control: alice" in region_text(bob, "#message")
            # alice acknowledges; bob's list shows it acknowledged
            await press(pa, "A")
            alice.driver.advance(10_000)
            await settle(pa)
            bob_screen.do(caught_up, bob, alice.link.last.snapshot.scan)
            states = {a.key: a.state for a in bob.link.last.alarms}
            assert states[first.key] == ACTIVE_ACK
            assert "● ACK" in region_text(bob, "#alarms")
            # bob asks for control; alice is asked and hands it over
            bob_screen.do(palette, "Control: request it")
            assert "asked alice" in region_text(bob, "#message")
            wait_for(lambda: alice.link.view().control.asked_by is not None, "the request")
            await settle(pa)
            dialog = await wait_for_screen(pa, ConfirmDialog)
            assert dialog.id == "control-request"
            assert "bob asks for control" in screen_text(alice)
            await press(pa, "y")
            await wait_for_main(pa)
            wait_for(lambda: bob.link.view().control.holder.identity.user == "bob", "bob")
            bob_screen.do(caught_up, bob, 0)
            await settle(pa)
            assert "● in control" in region_text(bob, "#status")
            assert "control: bob (terminal, c2)" in region_text(alice, "#status")
            assert "bob (operator, terminal, c2) is in control now" in \
                region_text(alice, "#message")
            # now bob acknowledges what is left, and alice sees it
            bob_screen.do(press, "A")
            bob.link.advance(10_000)
            await caught_up(pa, alice, bob.link.last.snapshot.scan)
            assert all(a.state != ACTIVE_UNACK for a in alice.link.last.alarms)
            assert "▲ UNACK" not in region_text(alice, "#alarms")
    finally:
        if bob_screen is not None:
            bob_screen.close()
        cell.stop()


async def test_an_hmi_whose_runtime_is_killed_says_runtime_lost_at_once(tmp_path):
    sock = tmp_path / "data" / "lost" / "runtime.sock"
    cell = RuntimeProcess(VALVE, sock, "--control", "faulty")
    app = screen(cell, "alice")
    async with app.run_test(size=(80, 24)) as pilot:
        app.driver.advance(3_000_000)
        await settle(pilot)
        assert "RUNTIME LOST" not in screen_text(app)
        cell.process.send_signal(signal.SIGKILL)
        cell.process.wait()
        wait_for(lambda: app.link.lost is not None, "the link to know")
        await settle(pilot)
        status = region_text(app, "#status")
        assert "RUNTIME LOST" in status and "▶" not in status  # no run state as if live
        assert "last known: AUTO, filter correct, scan 301" in screen_text(app) or \
            "last known" in status
        assert "RUNTIME LOST" in region_text(app, "#banners")
        assert app.has_class("-lost")  # the panels are greyed
        await press(pilot, "space")  # a command: not sent, said why
        assert "REFUSED" in region_text(app, "#message")
        assert "connection closed" in region_text(app, "#message")
        await press(pilot, "q")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await drain(pilot)


async def test_quitting_an_hmi_in_control_asks_stop_or_leave_running(tmp_path):
    sock = tmp_path / "data" / "quit" / "runtime.sock"
    cell = RuntimeProcess(VALVE, sock)
    try:
        app = screen(cell, "alice")
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot)
            await press(pilot, "q")
            dialog = await wait_for_screen(pilot, ConfirmDialog)
            assert dialog.title_text == "Quit: stop the cell, or leave it running?"
            text = screen_text(app)
            assert "y: stop the cell" in text and "g: leave it running" in text
            await press(pilot, "g")
            await drain(pilot)
        assert app.stop_cell is False
        app.link.leave(stop_cell=app.stop_cell)
        assert cell.process.poll() is None  # it runs on
        viewer = screen(cell, "v", want_control=False, role="viewer")
        async with viewer.run_test(size=SIZE) as pilot:
            await settle(pilot)
            await press(pilot, "q")
            dialog = await wait_for_screen(pilot, ConfirmDialog)
            assert dialog.title_text == "Quit this screen?"
            assert "keeps running" in screen_text(viewer)
            await press(pilot, "y")
            await drain(pilot)
        assert viewer.stop_cell is False
    finally:
        cell.stop()
