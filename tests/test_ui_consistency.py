"""Regressions: the frame's snapshot and the recorder's history must be of the same
scan, whatever the scan thread does while the UI builds a frame.

The live app scans in a thread; the UI reads the latest snapshot and the recorder's constraint
history to build a frame. If a scan lands between those two reads, a constraint violated in the
snapshot can be "not violated now" in the history (its episode just ended), and the
constraints panel asked for the start time of an episode that had none:
``seconds(None)``, the HMI died after ~30 s on ``--control faulty``. These tests make the scan
thread win that race deterministically: the recorder's lock runs one scan before the UI
thread gets it.
"""

from __future__ import annotations

from ui_harness import region_text, run_until
from ui_scenarios import VALVE, make_app

from hmi.ui.constraints_panel import ConstraintsPanel
from hmi.ui.headless import drain
from tests.conftest import make_session


class ScanFirst:
    """The recorder's lock, but the first time the UI thread asks for it, one scan runs first
    (the scan thread got there a moment earlier)."""

    def __init__(self, lock, scan):
        self.lock = lock
        self.scan = scan
        self.armed = True

    def __enter__(self):
        if self.armed:
            self.armed = False
            self.scan()
        return self.lock.__enter__()

    def __exit__(self, *exc):
        return self.lock.__exit__(*exc)


def last_scan_of_an_episode(control: str = "faulty", limit: int = 3000) -> tuple[int, str]:
    """A scan after which a violation episode ends (the same run, replayed on a twin engine)."""
    twin = make_session(VALVE, control=control)
    before = twin.scan_once().snapshot
    for _ in range(limit):
        after = twin.scan_once().snapshot
        ended = set(before.filter_report.violated_names) - set(after.filter_report.violated_names)
        if ended:
            return before.scan, sorted(ended)[0]
        before = after
    raise AssertionError("no violation episode ended")


async def test_a_scan_landing_while_a_frame_is_built_does_not_mix_two_scans():
    scan, name = last_scan_of_an_episode()
    app = make_app(control="faulty")
    async with app.run_test(size=(100, 30)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.scan == scan, 60, f"scan {scan}")
        assert name in app.link.session.last.snapshot.filter_report.violated_names
        app.link.recorder._lock = ScanFirst(app.link.recorder._lock, app.link.session.scan_once)
        app.poll(force=True)  # once a TypeError in the constraints panel
        await drain(pilot)
        frame = app.frame
        assert frame.snapshot.scan == scan + 1  # the newest scan, with its own history
        assert name not in frame.snapshot.filter_report.violated_names
        stats = frame.constraints[name]
        assert stats.since_us is None and stats.last_us == frame.snapshot.time_us - \
            app.link.session.period_us
        for violated in frame.snapshot.filter_report.violated_names:
            assert frame.constraints[violated].since_us is not None
        assert name in app.query_one(ConstraintsPanel).row_names
        assert "last" in region_text(app, "#constraints")
