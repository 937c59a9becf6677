"""hmi.session.reset_guard: a confirmed fault reset is carried out only if it still does what
its dialog showed, else declined with what changed (the hub and the in-process link both take
confirmed resets through it)."""

from __future__ import annotations

from hmi.engine.commands import FaultReset
from hmi.explain.reset import reset_preview
from hmi.session.reset_guard import command_as_shown
from tests.conftest import PROJECTS, make_session

VALVE = PROJECTS / "cispi_valve"


def latched_session():
    """The faulty program under safe blocking: latched, the violation gone since (so a
    reset would release the latch)."""
    session = make_session(VALVE, control="faulty", policy="block")
    while True:
        snap = session.scan_once().snapshot
        if snap.latched and snap.filter_report is not None and not snap.filter_report.violations:
            return session
        assert session.engine.now < 20_000_000, "no latch left without its cause"



def test_a_reset_that_does_what_was_shown_is_carried_out():
    session = latched_session()
    now = session.last
    shown = reset_preview(now.snapshot, now.alarms)
    assert any(line.resets for line in shown)
    result, declined = command_as_shown(session, FaultReset(), shown, now.snapshot.scan)
    assert not declined and result.accepted
    assert "safe-state latch released" in result.message


def test_a_reset_confirmed_on_what_no_longer_holds_is_declined_with_what_changed():
    session = latched_session()
    seen = session.last.snapshot.scan
    said = []  # what the journal is told: the session's origin and details at the time
    session.listeners.append(lambda command, result, last:
                             said.append((result, session.origin, session.origin_details)))
    result, declined = command_as_shown(session, FaultReset(), (), seen, "terminal:alice",
                                        {"reason": "valve checked"})
    assert declined and not result.accepted
    assert result.message.startswith("not done, asked again: what it would do changed")
    assert "now: ✓ will be reset: outputs held safe" in result.message
    assert session.last.snapshot.latched  # nothing was done
    assert said == [(result, "terminal:alice", {"reason": "valve checked"})]
