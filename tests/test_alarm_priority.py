"""ISA-18.2 in the alarm list: the priority of an alarm that is active or
unacknowledged never goes down; it starts afresh only once the alarm has left the list."""

from __future__ import annotations

from hmi.engine.commands import Acknowledge, ManualOutput, SetMode, SetPolicy
from hmi.explain.alarms import ACTIVE_UNACK, AlarmManager
from tests.conftest import PROJECTS, make_session
from tests.test_explain import make_exp

KEY = "constraint:CSs2"  # never hold the open order when the valve is open


def test_a_refused_manual_order_does_not_demote_an_unacknowledged_p1():
    """Seen in a hands-on review: under the monitor policy the faulty program's open order on
    an open valve is written (P1, NOT corrected); switched to correct and manual, the same
    order requested by hand is refused by the filter (a P3 situation). The row stayed the
    same alarm and became P3, unacknowledged; the journal said high → low."""
    session = make_session(PROJECTS / "cispi_valve", control="faulty", policy="monitor")
    for _ in range(2000):
        snap = session.scan_once()
        alarm = next((a for a in snap.alarms if a.key == KEY), None)
        if alarm is not None:
            break
    assert alarm is not None and alarm.priority == 1 and alarm.state == ACTIVE_UNACK
    assert session.command(SetPolicy("correct")).accepted
    assert session.command(SetMode(True)).accepted
    severities = set()
    for _ in range(2000):  # hold O on by hand: refused whenever the valve is open
        session.command(ManualOutput("O", True))
        snap = session.scan_once()
        severities |= {e.severity for e in snap.explanations if e.key == KEY}
        listed = next((a for a in snap.alarms if a.key == KEY), None)
        assert listed is not None, "an unacknowledged alarm left the list"
        assert listed.priority == 1, f"P1 became P{listed.priority}: {listed.text}"
        if "low" in severities and listed.active:
            break
    assert "low" in severities  # the situation itself did read low: the rule was exercised
    session.command(Acknowledge(KEY))  # acknowledged: still listed, still P1
    assert session.alarms.alarms[KEY].priority == 1


def test_priority_keeps_the_highest_while_listed_then_starts_afresh():
    m = AlarmManager()
    m.update((make_exp("k", severity="high"),), 1, 0)
    m.update((make_exp("k", severity="low"),), 2, 1)
    assert m.listed()[0].priority == 1  # active, unacknowledged
    m.acknowledge("k", 3, 2)
    m.update((make_exp("k", severity="low"),), 4, 3)
    assert m.listed()[0].priority == 1  # active, acknowledged: still listed
    m.update((), 5, 4)  # acknowledged and cleared: it leaves the list
    assert not m.listed()
    m.update((make_exp("k", severity="low"),), 6, 5)
    assert m.listed()[0].priority == 3  # a new alarm
    m.update((), 7, 6)  # cleared, unacknowledged: still listed
    events = m.update((make_exp("k", severity="medium"),), 8, 7)  # returns, higher
    assert m.listed()[0].priority == 2 and events[0].severity == "medium"
    m.update((make_exp("k", severity="low"),), 9, 8)
    assert m.listed()[0].priority == 2
