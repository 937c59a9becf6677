"""Alarms with the ISA-18.2 states, driven by the explanations that need the operator.

    (normal) --condition--> active-unacknowledged --ack--> active-acknowledged
    active-unacknowledged --clears--> cleared-unacknowledged --ack--> (normal, removed)
    active-acknowledged --clears--> (normal, removed)
    cleared-unacknowledged --returns--> active-unacknowledged

A latched situation (diagnoser fault, safe blocking) keeps its condition true until a fault
reset, so its alarm stays active until then. A chattering alarm — one that returns more than
CHATTER_RETURNS times within CHATTER_WINDOW — is collapsed: it stays in the list as one
active alarm with a count, and clears only once its condition has stayed clear for
CHATTER_WINDOW, instead of flooding the list with transitions. That is an off-delay (one of
ISA-18.2's chattering-alarm remedies, next to deadbands and shelving) applied to the list
only: the journal still gets every change of the condition the operator could have seen, as
compact ``condition-cleared`` / ``condition-returned`` events with the running count, and
the final ``cleared`` says since when the condition had really been clear.

**Priority never goes down while the alarm is listed.** An alarm's situation may change its
severity while it lasts (a violation first passed unsafe under the monitor policy, then a
refused manual order on the same constraint, reads "low"). While the alarm is active or
unacknowledged its priority keeps the highest it had: an operator who saw a P1 must not find
it quietly demoted to P3 before acknowledging it. It starts afresh only once it has left the
list (acknowledged and cleared).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

from hmi.explain.model import Explanation
from hmi.timefmt import seconds

ACTIVE_UNACK = "active-unacknowledged"
ACTIVE_ACK = "active-acknowledged"
CLEARED_UNACK = "cleared-unacknowledged"
CHATTER_RETURNS = 3
CHATTER_WINDOW_US = 60_000_000
PRIORITY = {"high": 1, "medium": 2, "low": 3}
LIST_ORDER = {ACTIVE_UNACK: 0, CLEARED_UNACK: 1, ACTIVE_ACK: 2}


def highest(old: str, new: str) -> str:
    """The severity of the two with the higher priority (the smaller P number)."""
    return old if PRIORITY.get(old, 3) < PRIORITY.get(new, 3) else new


@dataclass(frozen=True)
class Alarm:
    key: str
    state: str
    severity: str
    text: str  # level 1 of its explanation
    device: str
    kind: str
    raised_scan: int
    raised_us: int
    changed_us: int
    returns: int = 0  # how many times it came back after clearing
    chattering: bool = False
    latched: bool = False
    explanation: Explanation | None = field(default=None, compare=False)

    @property
    def active(self) -> bool:
        return self.state in (ACTIVE_UNACK, ACTIVE_ACK)

    @property
    def acknowledged(self) -> bool:
        return self.state == ACTIVE_ACK

    @property
    def priority(self) -> int:
        return PRIORITY.get(self.severity, 3)


@dataclass(frozen=True)
class AlarmEvent:
    """One transition, for the journal: raised, acknowledged, cleared, returned, chattering,
    and for a collapsed (chattering) alarm held active in the list, condition-cleared and
    condition-returned: its condition changed, the list did not."""

    key: str
    event: str
    state: str  # the state after the transition ("normal" once removed)
    severity: str
    text: str
    scan: int
    time_us: int
    returns: int = 0
    note: str = ""  # what the state alone does not say (a held alarm's real clear time)


class AlarmManager:
    def __init__(self) -> None:
        self.alarms: dict[str, Alarm] = {}
        self.returns: dict[str, deque[int]] = {}
        self.clear_since: dict[str, int] = {}
        self._listed: tuple[Alarm, ...] | None = ()  # chattering alarms: condition clear since

    def update(self, explanations: tuple[Explanation, ...], scan: int, now: int
               ) -> list[AlarmEvent]:
        events: list[AlarmEvent] = []
        present = {e.key: e for e in explanations if e.alarm}
        for key, exp in present.items():
            alarm = self.alarms.get(key)
            was_clear = self.clear_since.pop(key, None) is not None
            if alarm is None:
                alarm = Alarm(key, ACTIVE_UNACK, exp.severity, exp.what, exp.device, exp.kind,
                              scan, now, now, latched=exp.latched, explanation=exp)
                self._put(key, alarm)
                events.append(self._event(alarm, "raised", scan, now))
            elif alarm.state == CLEARED_UNACK:
                history = self.returns.setdefault(key, deque())
                history.append(now)
                while history and now - history[0] > CHATTER_WINDOW_US:
                    history.popleft()
                chattering = alarm.chattering or len(history) > CHATTER_RETURNS
                alarm = replace(alarm, state=ACTIVE_UNACK, changed_us=now,
                                returns=alarm.returns + 1, chattering=chattering,
                                severity=highest(alarm.severity, exp.severity),
                                text=exp.what, explanation=exp)
                self._put(key, alarm)
                events.append(self._event(alarm, "returned", scan, now))
                if chattering:
                    events.append(self._event(alarm, "chattering", scan, now))
            else:
                if alarm.chattering and was_clear:
                    # A collapsed alarm's condition came back while still shown active: the
                    # list does not change, the journal must still see it.
                    alarm = replace(alarm, returns=alarm.returns + 1)
                    events.append(self._event(alarm, "condition-returned", scan, now))
                if alarm.explanation is not exp:
                    alarm = replace(alarm, severity=highest(alarm.severity, exp.severity),
                                    text=exp.what, explanation=exp, latched=exp.latched)
                self._put(key, alarm)
        for key, alarm in list(self.alarms.items()):
            if key in present or alarm.state == CLEARED_UNACK:
                continue
            note = ""
            if alarm.chattering:
                since = self.clear_since.get(key)
                if since is None:
                    since = self.clear_since[key] = now
                    events.append(self._event(alarm, "condition-cleared", scan, now,
                                              "held active while chattering"))
                if now - since < CHATTER_WINDOW_US:
                    continue
                note = f"condition clear since {seconds(since)} s (held while chattering)"
            events.extend(self._clear(alarm, scan, now, note))
        return events

    def _clear(self, alarm: Alarm, scan: int, now: int, note: str = "") -> list[AlarmEvent]:
        self.clear_since.pop(alarm.key, None)
        if alarm.state == ACTIVE_ACK:
            self._drop(alarm.key)
            self.returns.pop(alarm.key, None)
            return [self._event(replace(alarm, state="normal"), "cleared", scan, now, note)]
        cleared = replace(alarm, state=CLEARED_UNACK, changed_us=now)
        self._put(alarm.key, cleared)
        return [self._event(cleared, "cleared", scan, now, note)]

    def acknowledge(self, key: str | None, scan: int, now: int) -> list[AlarmEvent]:
        """Acknowledge one alarm (by key) or all (None)."""
        keys = [key] if key is not None else list(self.alarms)
        events = []
        for k in keys:
            alarm = self.alarms.get(k)
            if alarm is None:
                continue
            if alarm.state == ACTIVE_UNACK:
                alarm = replace(alarm, state=ACTIVE_ACK, changed_us=now)
                self._put(k, alarm)
                events.append(self._event(alarm, "acknowledged", scan, now))
            elif alarm.state == CLEARED_UNACK:
                self._drop(k)
                self.returns.pop(k, None)
                events.append(self._event(replace(alarm, state="normal"), "acknowledged",
                                          scan, now))
        return events

    def _put(self, key: str, alarm: Alarm) -> None:
        if self.alarms.get(key) is not alarm:
            self.alarms[key] = alarm
            self._listed = None

    def _drop(self, key: str) -> None:
        del self.alarms[key]
        self._listed = None

    def listed(self) -> tuple[Alarm, ...]:
        """The alarm list: unacknowledged first — active ones, then those whose condition
        already cleared (they only wait for the acknowledgement) — then acknowledged; in each
        group by priority, newest first. Sorted again only after a change (it is asked for
        every scan)."""
        if self._listed is None:
            self._listed = tuple(sorted(self.alarms.values(),
                                        key=lambda a: (LIST_ORDER.get(a.state, 1), a.priority,
                                                       -a.changed_us)))
        return self._listed

    @staticmethod
    def _event(alarm: Alarm, event: str, scan: int, now: int, note: str = "") -> AlarmEvent:
        return AlarmEvent(alarm.key, event, alarm.state, alarm.severity, alarm.text, scan, now,
                          alarm.returns, note)
