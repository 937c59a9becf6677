"""plchmi's alarms as OPC UA Part 9 conditions (AlarmConditionType), without asyncua.

The alarm model stays plchmi's own (hmi.explain.alarms, ISA-18.2); this module only says
how each of its states reads as a condition and which condition events to send:

    ISA-18.2 state            ActiveState  AckedState  Retain
    active-unacknowledged     Active       Unacked     true
    active-acknowledged       Active       Acked       true
    cleared-unacknowledged    Inactive     Unacked     true
    (normal: gone from list)  Inactive     Acked       false

Severity comes from the ISA-18.2 priority (SEVERITY), Message is level 1 of the alarm's
explanation, and the other levels travel as the event type's own properties (Why,
Consequences, Policies, Detail).

Transitions reach the publisher two ways: the alarm events carried by snapshots (raised,
cleared, returned...), and the alarm list of the latest snapshot, compared with what was
last sent. The second catches what snapshots do not carry — an acknowledgement is journalled
at once by the session's command listener, not in the next snapshot — and anything the
publisher coalesced. A condition event is sent only when the condition's state (or its count
of returns) differs from the last one sent for it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from hmi.explain.alarms import (
    ACTIVE_ACK,
    ACTIVE_UNACK,
    CLEARED_UNACK,
    Alarm,
    AlarmEvent,
    Shelf,
)
from hmi.explain.model import Explanation

NORMAL = "normal"
# ISA-18.2 priority -> OPC UA Severity (1..1000). Part 9's bands put 801-1000 high,
# 401-600 medium, 201-400 medium-low; SCADAs map the same bands to their own priorities
# (Ignition: 801+ critical, 401-600 medium, 201-400 low), so a low-priority alarm stays an
# alarm there (1-200 is "diagnostic").
SEVERITY = {"high": 900, "medium": 500, "low": 300}
HMI_USER = "plchmi HMI"  # ClientUserId of what the cell's own HMI (or a script) did
# Part 9's ShelvingState names (ShelvedStateMachineType).
UNSHELVED, TIMED, ONE_SHOT = "Unshelved", "TimedShelved", "OneShotShelved"


@dataclass(frozen=True)
class ConditionView:
    """One condition event: the alarm's state after a transition, as Part 9 fields."""

    key: str  # the alarm's key: the condition's name and the end of its node id
    transition: str  # raised, acknowledged, cleared, returned, ...
    state: str  # the ISA-18.2 state after it (NORMAL once gone from the list)
    severity: int
    priority: str  # high, medium, low
    device: str
    kind: str
    message: str  # level 1 of the explanation
    why: str  # level 2
    consequences: str  # level 3
    policies: str  # level 4
    detail: str  # level 5, the engineering detail, where the explanation has one
    time_us: int  # when it happened, in the run's time
    returns: int
    chattering: bool
    latched: bool
    user: str  # who acknowledged (ClientUserId); "" otherwise
    comment: str
    shelving: str = "Unshelved"  # Part 9 ShelvingState: Unshelved, TimedShelved, OneShotShelved
    unshelve_ms: float = 0.0  # a timed shelf: time left until it ends (Part 9 UnshelveTime)

    @property
    def active(self) -> bool:
        return self.state in (ACTIVE_UNACK, ACTIVE_ACK)

    @property
    def acked(self) -> bool:
        return self.state in (ACTIVE_ACK, NORMAL)

    @property
    def shelved(self) -> bool:
        return self.shelving != UNSHELVED

    @property
    def retain(self) -> bool:
        """Part 9: a condition is retained while it is of interest to the operator: active,
        or not yet acknowledged."""
        return self.state != NORMAL


class ConditionTracker:
    """Turns what the scans and the latest snapshot say into the condition events to send."""

    def __init__(self) -> None:
        # key -> (state, returns, shelving) last sent
        self.sent: dict[str, tuple[str, int, str]] = {}
        self.alarms: dict[str, Alarm] = {}  # key -> the last alarm seen (for its texts)
        self.acks: dict[str, tuple[str, str]] = {}  # key -> (user, comment) of a pending ack
        self.actors: dict[str, str] = {}  # key -> who shelved or unshelved it last
        self.shelves: dict[str, Shelf] = {}  # the shelved alarms, as last seen
        self.now_us = 0  # the time of the latest snapshot

    def acknowledged_by(self, key: str, user: str, comment: str) -> None:
        """An acknowledgement is on its way from an OPC UA client: name it in the event."""
        self.acks[key] = (user, comment)

    def acted(self, key: str, user: str) -> None:
        """Someone shelves or unshelves `key`: the shelving event names them."""
        self.actors[key] = user

    def commented(self, key: str, user: str, text: str) -> list[ConditionView]:
        """A comment on a condition (Part 9 AddComment): an event of its own, the
        condition's state as last sent, with the comment and who wrote it."""
        alarm = self.alarms.get(key)
        last = self.sent.get(key)
        if alarm is None or last is None:
            return []
        state, returns, shelving = last
        shelf = self.shelves.get(key)
        remaining = 0.0
        if shelf is not None and shelf.until_us is not None:
            remaining = max(0.0, (shelf.until_us - self.now_us) / 1000)
        return [_view(key, "comment", state, alarm, self.now_us, returns, user, text,
                      shelving, remaining)]

    def update(self, batches: Iterable[tuple[tuple[AlarmEvent, ...], tuple[Alarm, ...]]],
               latest: tuple[Alarm, ...], now_us: int,
               shelved: tuple[tuple[Alarm, Shelf], ...] = ()) -> list[ConditionView]:
        """The events to send, oldest first: from the scans' alarm events (`batches`, in
        order), then from the latest alarm list (`latest`, and the alarms shelved out of
        it: still conditions, flagged as shelved)."""
        views: list[ConditionView] = []
        self.now_us = now_us
        self.shelves = {alarm.key: shelf for alarm, shelf in shelved}
        for events, alarms in batches:
            self._remember(alarms)
            for event in events:
                views += self._emit(event.key, event.state, event.event, event.time_us,
                                    event.returns)
        present = (*latest, *(alarm for alarm, _ in shelved))
        self._remember(present)
        for alarm in present:
            views += self._emit(alarm.key, alarm.state, "", alarm.changed_us, alarm.returns)
        listed = {alarm.key for alarm in present}
        for key, (state, returns, _) in list(self.sent.items()):
            if key not in listed:
                transition = "acknowledged" if state == CLEARED_UNACK else "cleared"
                views += self._emit(key, NORMAL, transition, now_us, returns)
        return views

    def retained(self) -> list[str]:
        """Keys of the conditions still of interest (what ConditionRefresh replays)."""
        return list(self.sent)

    def _remember(self, alarms: Iterable[Alarm]) -> None:
        for alarm in alarms:
            self.alarms[alarm.key] = alarm

    def _emit(self, key: str, state: str, transition: str, time_us: int, returns: int
              ) -> list[ConditionView]:
        """The event for a condition now in `state` (none if that was the last sent);
        `transition` "" lets the change itself name it."""
        last = self.sent.get(key)  # None: nothing of interest sent (or sent as normal)
        shelf = self.shelves.get(key) if state != NORMAL else None
        shelving = UNSHELVED if shelf is None else (
            ONE_SHOT if shelf.until_us is None else TIMED)
        now = (state, returns, shelving)
        if (last is None and state == NORMAL) or last == now:
            return []
        if not transition:
            transition = _inferred(state, returns, last, shelving)
            if transition == "shelved" and shelf is not None:
                time_us = shelf.since_us
            elif transition == "unshelved":
                time_us = self.now_us
        if state == NORMAL:
            self.sent.pop(key, None)
        else:
            self.sent[key] = now
        alarm = self.alarms.get(key)
        if state == NORMAL:
            self.alarms.pop(key, None)
        user, comment = ("", "")
        if transition == "acknowledged":
            user, comment = self.acks.pop(key, (HMI_USER, ""))
        elif transition in ("shelved", "unshelved"):
            user = self.actors.pop(key, HMI_USER)
        remaining = 0.0
        if shelf is not None and shelf.until_us is not None:
            remaining = max(0.0, (shelf.until_us - self.now_us) / 1000)
        return [_view(key, transition, state, alarm, time_us, returns, user, comment,
                      shelving, remaining)]


def _inferred(state: str, returns: int, last: tuple[str, int, str] | None,
              shelving: str) -> str:
    """The transition that leads to a condition's state, when only the state is known."""
    if last is not None and last[:2] == (state, returns):
        return "unshelved" if shelving == UNSHELVED else "shelved"
    return {ACTIVE_UNACK: "returned" if returns else "raised",
            ACTIVE_ACK: "acknowledged", CLEARED_UNACK: "cleared"}.get(state, "changed")


def _view(key: str, transition: str, state: str, alarm: Alarm | None, time_us: int,
          returns: int, user: str, comment: str, shelving: str, remaining_ms: float
          ) -> ConditionView:
    explanation: Explanation | None = alarm.explanation if alarm else None
    priority = alarm.severity if alarm else "low"
    return ConditionView(
        key=key, transition=transition, state=state, severity=SEVERITY.get(priority, 300),
        priority=priority, device=alarm.device if alarm else "",
        kind=alarm.kind if alarm else "", message=alarm.text if alarm else key,
        why=explanation.why if explanation else "",
        consequences=explanation.consequences if explanation else "",
        policies=explanation.policies_text() if explanation else "",
        detail=getattr(explanation, "detail", "") or "",
        time_us=time_us, returns=returns, chattering=bool(alarm and alarm.chattering),
        latched=bool(alarm and alarm.latched), user=user, comment=comment,
        shelving=shelving, unshelve_ms=remaining_ms)
