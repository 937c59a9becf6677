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

from hmi.explain.alarms import ACTIVE_ACK, ACTIVE_UNACK, CLEARED_UNACK, Alarm, AlarmEvent
from hmi.explain.model import Explanation

NORMAL = "normal"
# ISA-18.2 priority -> OPC UA Severity (1..1000). Part 9's bands put 801-1000 high,
# 401-600 medium, 201-400 medium-low; SCADAs map the same bands to their own priorities
# (Ignition: 801+ critical, 401-600 medium, 201-400 low), so a low-priority alarm stays an
# alarm there (1-200 is "diagnostic").
SEVERITY = {"high": 900, "medium": 500, "low": 300}
HMI_USER = "plchmi HMI"  # ClientUserId of what the cell's own HMI (or a script) did


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

    @property
    def active(self) -> bool:
        return self.state in (ACTIVE_UNACK, ACTIVE_ACK)

    @property
    def acked(self) -> bool:
        return self.state in (ACTIVE_ACK, NORMAL)

    @property
    def retain(self) -> bool:
        """Part 9: a condition is retained while it is of interest to the operator: active,
        or not yet acknowledged."""
        return self.state != NORMAL


class ConditionTracker:
    """Turns what the scans and the latest snapshot say into the condition events to send."""

    def __init__(self) -> None:
        self.sent: dict[str, tuple[str, int]] = {}  # key -> (state, returns) last sent
        self.alarms: dict[str, Alarm] = {}  # key -> the last alarm seen (for its texts)
        self.acks: dict[str, tuple[str, str]] = {}  # key -> (user, comment) of a pending ack

    def acknowledged_by(self, key: str, user: str, comment: str) -> None:
        """An acknowledgement is on its way from an OPC UA client: name it in the event."""
        self.acks[key] = (user, comment)

    def update(self, batches: Iterable[tuple[tuple[AlarmEvent, ...], tuple[Alarm, ...]]],
               latest: tuple[Alarm, ...], now_us: int) -> list[ConditionView]:
        """The events to send, oldest first: from the scans' alarm events (`batches`, in
        order), then from the latest alarm list (`latest`)."""
        views: list[ConditionView] = []
        for events, alarms in batches:
            self._remember(alarms)
            for event in events:
                view = self._emit(event.key, event.state, event.event, event.time_us,
                                  event.returns)
                if view is not None:
                    views.append(view)
        self._remember(latest)
        listed = set()
        for alarm in latest:
            listed.add(alarm.key)
            view = self._emit(alarm.key, alarm.state, _inferred(alarm), alarm.changed_us,
                              alarm.returns)
            if view is not None:
                views.append(view)
        for key, (state, returns) in list(self.sent.items()):
            if key not in listed and state != NORMAL:
                transition = "acknowledged" if state == CLEARED_UNACK else "cleared"
                view = self._emit(key, NORMAL, transition, now_us, returns)
                if view is not None:
                    views.append(view)
        return views

    def retained(self) -> list[str]:
        """Keys of the conditions still of interest (what ConditionRefresh replays)."""
        return [key for key, (state, _) in self.sent.items() if state != NORMAL]

    def _remember(self, alarms: tuple[Alarm, ...]) -> None:
        for alarm in alarms:
            self.alarms[alarm.key] = alarm

    def _emit(self, key: str, state: str, transition: str, time_us: int, returns: int
              ) -> ConditionView | None:
        last = self.sent.get(key)  # None: nothing of interest sent (or sent as normal)
        if (last is None and state == NORMAL) or last == (state, returns):
            return None
        self.sent[key] = (state, returns)
        alarm = self.alarms.get(key)
        user, comment = ("", "")
        if transition == "acknowledged":
            user, comment = self.acks.pop(key, (HMI_USER, ""))
        if state == NORMAL:
            self.sent.pop(key, None)
            self.alarms.pop(key, None)
        return _view(key, transition, state, alarm, time_us, returns, user, comment)


def _inferred(alarm: Alarm) -> str:
    """The transition that leads to an alarm's state, when only the state is known."""
    return {ACTIVE_UNACK: "returned" if alarm.returns else "raised",
            ACTIVE_ACK: "acknowledged", CLEARED_UNACK: "cleared"}.get(alarm.state, "changed")


def _view(key: str, transition: str, state: str, alarm: Alarm | None, time_us: int,
          returns: int, user: str, comment: str) -> ConditionView:
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
        latched=bool(alarm and alarm.latched), user=user, comment=comment)
