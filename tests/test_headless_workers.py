"""The headless driver waits for a worker thread that takes the machine's time (a database
read on a loaded machine), however many rounds of the app's messages that would be."""

from __future__ import annotations

import threading
import time

from hmi.ui.app import PlcHmiApp
from hmi.ui.headless import drain
from tests.conftest import PROJECTS, make_session


async def test_a_slow_worker_thread_is_waited_for_not_counted_in_rounds(monkeypatch):
    # few rounds allowed: a driver that spins rounds while the thread works runs out of
    # them long before the thread ends (a soak farm's replay did with 10,000, at load 15)
    monkeypatch.setattr("hmi.ui.headless.MAX_ROUNDS", 50)
    app = PlcHmiApp(make_session(PROJECTS / "cispi_valve"), live=False, show_measured=False)
    release = threading.Event()
    waited = 0

    def slow_read() -> str:
        release.wait(60)
        return "read"

    async with app.run_test(size=(80, 24)) as pilot:
        await drain(pilot)
        worker = app.run_worker(slow_read, thread=True, name="slow read")
        timer = threading.Timer(1.0, release.set)
        timer.start()
        started = time.monotonic()
        await drain(pilot)
        waited = time.monotonic() - started
        timer.cancel()
        assert release.is_set() and worker.result == "read"
    assert waited >= 0.9
