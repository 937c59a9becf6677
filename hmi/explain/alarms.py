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

**Shelving** (ISA-18.2 §11, OPC UA Part 9 Shelving): the operator takes an alarm out of the
list for a while — timed (back after a duration, at most MAX_SHELVE_US) or one-shot (back once
its condition clears) — without silencing its record: a shelved alarm keeps its states and
every transition is journalled; it comes back by itself (``unshelved``, with why). A latched
alarm (safe blocking, a diagnoser's fault) cannot be shelved, and one that latches while
shelved comes back at once: a safety alarm is never hidden. ``Acknowledge all`` leaves shelved
alarms alone. **Comments**: the operator's note on an alarm, journalled and kept on it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

from hmi.explain.model import Explanation, Policy
from hmi.timefmt import format_duration, seconds

ACTIVE_UNACK = "active-unacknowledged"
ACTIVE_ACK = "active-acknowledged"
CLEARED_UNACK = "cleared-unacknowledged"
CHATTER_RETURNS = 3
CHATTER_WINDOW_US = 60_000_000
MAX_SHELVE_US = 8 * 3_600_000_000  # OPC UA MaxTimeShelved: a shelf is never forever
PRIORITY = {"high": 1, "medium": 2, "low": 3}
LIST_ORDER = {ACTIVE_UNACK: 0, CLEARED_UNACK: 1, ACTIVE_ACK: 2}
FLOOD_LIMIT = 20  # constraint alarms listed one by one; past it, an alarm flood
FLOOD_KEY = "alarm-flood"


def _flood_what(held: int) -> str:
    return (f"Alarm flood: {held} more safety rule{'s' if held != 1 else ''} broken than "
            "the list shows")


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
    comment: str = ""  # the operator's last comment on it

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


@dataclass(frozen=True)
class Shelf:
    """How an alarm is shelved: until a time, or (None) once, until its condition clears."""

    since_us: int
    until_us: int | None

    def describe(self) -> str:
        if self.until_us is None:
            return "once, until its condition clears"
        return f"for {format_duration(self.until_us - self.since_us)}"


class AlarmManager:
    def __init__(self) -> None:
        self.shelved: dict[str, Shelf] = {}
        self.alarms: dict[str, Alarm] = {}
        self.returns: dict[str, deque[int]] = {}
        self.clear_since: dict[str, int] = {}
        self._listed: tuple[Alarm, ...] | None = ()  # chattering alarms: condition clear since
        # An alarm flood going on: (since, its first scan, most alarms held, its
        # explanation); None: none.
        self._flood: tuple[int, int, int, Explanation | None] | None = None

    def settled(self, explanations: tuple[Explanation, ...]) -> bool:
        """Whether :meth:`update` with these explanations (those of its last call) would
        change nothing, now or later: nothing shelved (a shelf runs out with time), no
        chattering alarm held active while clear (held for a while), each alarm of these
        explanations listed with that very explanation and not cleared (a cleared one would
        return), every other alarm cleared already and waiting for its acknowledgement (an
        active one would clear)."""
        if self.shelved or self.clear_since:
            return False
        alarms = self.alarms
        present = 0
        for e in explanations:
            if e.alarm:
                alarm = alarms.get(e.key)
                if alarm is None or alarm.explanation is not e or alarm.state == CLEARED_UNACK:
                    return False
                present += 1
        if present == len(alarms):
            return True
        keys = {e.key for e in explanations if e.alarm}
        return all(a.state == CLEARED_UNACK for k, a in alarms.items() if k not in keys)

    def update(self, explanations: tuple[Explanation, ...], scan: int, now: int
               ) -> list[AlarmEvent]:
        events: list[AlarmEvent] = []
        present = self._contain_flood({e.key: e for e in explanations if e.alarm}, scan, now)
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
        if self.shelved:
            events.extend(self._expire_shelves(scan, now))
        return events

    # -- alarm floods ---------------------------------------------------------------------------
    def _contain_flood(self, present: dict[str, Explanation], scan: int, now: int
                       ) -> dict[str, Explanation]:
        """ISA-18.2's flood: more alarms than an operator can handle at once. The list holds
        at most FLOOD_LIMIT constraint alarms one by one (those already listed keep their
        place, cleared-unacknowledged ones included); the constraint alarms past it are
        held out of the list and counted in one FLOOD_KEY alarm, raised when the flood
        starts and cleared when it ends, its count updated in place (not journalled at
        every change). Latched alarms and every other kind are never held: a safety alarm is
        never hidden, and only the rules' alarms come by the hundred. Nothing else changes:
        the filter acts on every rule; the constraints panel shows them all."""
        room = FLOOD_LIMIT - sum(1 for a in self.alarms.values() if a.kind == "constraint")
        held = []
        for key, exp in present.items():
            if exp.kind != "constraint" or exp.latched or key in self.alarms:
                continue
            if room > 0:
                room -= 1
            else:
                held.append(key)
        if not held:
            self._flood = None
            return present
        broken = sum(1 for e in present.values() if e.kind == "constraint")
        device = present[held[0]].device
        hold = set(held)
        present = {k: e for k, e in present.items() if k not in hold}
        since, since_scan, peak, last = self._flood or (now, scan, 0, None)
        peak = max(peak, len(held))
        if last is None or last.what != _flood_what(len(held)) or \
                not last.why.startswith(f"{broken} "):
            last = Explanation(
                FLOOD_KEY, "flood", "high", device, _flood_what(len(held)),
                f"{broken} safety rules are broken at once. "
                f"The alarm list shows at most {FLOOD_LIMIT} of them one by one and counts "
                "the others here (an alarm flood, as ISA-18.2 names it), so that no alarm "
                f"that needs you is lost among them. Since {seconds(since)} s.",
                "The filter still acts on every rule: each broken one is corrected, or the "
                "safe state written, as usual; only the list is shortened. The constraints "
                "panel shows every rule broken now. Acknowledging the listed alarms makes "
                "room for the next ones.",
                (Policy("constraints", "See the constraints panel",
                        "every rule broken now, with what the filter did", None, True),),
                since_scan, since,
                detail=f"{len(held)} constraint alarms held out of the list (at most {peak} "
                       f"since {seconds(since)} s); FLOOD_LIMIT {FLOOD_LIMIT}.")
        self._flood = (since, since_scan, peak, last)
        present[FLOOD_KEY] = last
        return present

    # -- shelving and comments -----------------------------------------------------------------
    def shelve(self, key: str, duration_us: int | None, scan: int, now: int
               ) -> tuple[list[AlarmEvent], str]:
        """Shelve one alarm; (events, "") or ([], why it is refused)."""
        alarm = self.alarms.get(key)
        if alarm is None:
            return [], f"no alarm {key} in the list"
        if alarm.latched and alarm.active:
            return [], ("a latched safety alarm cannot be shelved: it goes with a fault reset "
                        "once its cause is gone")
        if key in self.shelved:
            return [], f"already shelved {self.shelved[key].describe()}"
        if duration_us is not None and not 0 < duration_us <= MAX_SHELVE_US:
            return [], "a shelving time is longer than zero and at most 8 h"
        if duration_us is None and not alarm.active:
            return [], "its condition has already cleared: acknowledge it instead"
        shelf = Shelf(now, None if duration_us is None else now + duration_us)
        self.shelved[key] = shelf
        self._listed = None
        return [self._event(alarm, "shelved", scan, now, shelf.describe())], ""

    def unshelve(self, key: str, scan: int, now: int, why: str = "by the operator"
                 ) -> list[AlarmEvent]:
        if self.shelved.pop(key, None) is None:
            return []
        self._listed = None
        alarm = self.alarms.get(key)
        if alarm is None:
            return [AlarmEvent(key, "unshelved", "normal", "", "", scan, now, 0, why)]
        return [self._event(alarm, "unshelved", scan, now, why)]

    def comment(self, key: str, text: str, scan: int, now: int) -> list[AlarmEvent]:
        alarm = self.alarms.get(key)
        if alarm is None:
            return []
        self._put(key, replace(alarm, comment=text))
        return [self._event(alarm, "comment", scan, now, text)]

    def _expire_shelves(self, scan: int, now: int) -> list[AlarmEvent]:
        events = []
        for key, shelf in list(self.shelved.items()):
            alarm = self.alarms.get(key)
            if alarm is None:
                why = "returned to normal"
            elif alarm.latched and alarm.active:
                why = "latched: a safety alarm is never hidden"
            elif shelf.until_us is not None and now >= shelf.until_us:
                why = "shelving time over"
            elif shelf.until_us is None and not alarm.active:
                why = "condition cleared: one-shot shelving over"
            else:
                continue
            events.extend(self.unshelve(key, scan, now, why))
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
        keys = [key] if key is not None else [k for k in self.alarms if k not in self.shelved]
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

    def shelved_listed(self) -> tuple[tuple[Alarm, Shelf], ...]:
        """The shelved alarms with their shelves (for the HMI: count, unshelve)."""
        return tuple((self.alarms[k], s) for k, s in self.shelved.items() if k in self.alarms)

    def listed(self) -> tuple[Alarm, ...]:
        """The alarm list: unacknowledged first — active ones, then those whose condition
        already cleared (they only wait for the acknowledgement) — then acknowledged; in each
        group by priority, newest first. Sorted again only after a change (it is asked for
        every scan)."""
        if self._listed is None:
            shown = (a for a in self.alarms.values() if a.key not in self.shelved)
            self._listed = tuple(sorted(shown,
                                        key=lambda a: (LIST_ORDER.get(a.state, 1), a.priority,
                                                       -a.changed_us)))
        return self._listed

    @staticmethod
    def _event(alarm: Alarm, event: str, scan: int, now: int, note: str = "") -> AlarmEvent:
        return AlarmEvent(alarm.key, event, alarm.state, alarm.severity, alarm.text, scan, now,
                          alarm.returns, note)
