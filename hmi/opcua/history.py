"""OPC UA HistoryRead (Part 11) from the cell's history: what a SCADA draws of the past.

The server does not record anything itself: the historian (hmi.history) records every scan
of the cell, and this answers HistoryRead from it, through its own read-only connection, in
a worker thread (a query never holds the server's event loop).

* **Variables**: every variable the historian records a signal for (an input's Value and
  FilteredValue, an output's ProgramValue and WrittenValue, each constraint, a diagnoser's
  State, a monitor's X, Y and State, the cell's Mode, Policy, Latched, ScanTime and
  ActiveAlarms) has the HistoryRead access bit and ``Historizing`` true. ReadRaw returns the
  stored samples (on change, or at the deadband), each stamped with its scan's time
  (``SourceTimestamp``: the same instants as the live values), with the variable's own
  type (a state by name). Where the history stops (the cell was not running, or history
  was lost) a value with the status ``BadDataLost`` marks the instant after the last one
  covered. More than ``MAX_VALUES`` values: a continuation point (the next value's time).
* **Events**: the Server object (``i=2253``) has the HistoryRead event notifier bit;
  ReadEvent returns the alarm transitions (as ``PlchmiAlarmType`` events: the condition's
  name, the transition, severity, message, who acknowledged) and the operator actions and
  session entries (as ``BaseEventType`` events, the action in the Message).

Part 11's bounds (ReturnBounds), ReadModified, ReadProcessed (aggregates) and ReadAtTime are
not served (BadHistoryOperationUnsupported from asyncua; a SCADA falls back on raw data).
"""

from __future__ import annotations

import asyncio
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from asyncua import ua
from asyncua.common.events import Event as UaEvent
from asyncua.server.history import HistoryStorageInterface
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes

from hmi.history.catalogue import BOOL, COUNTER, ENUM, Signal
from hmi.history.query import HistoryReader
from hmi.history.store import Event, Sample, Segment
from hmi.history.target import Target, open_store

MAX_VALUES = 10_000  # per answer; more: a continuation point
EPOCH = ua.DateTime(1970, 1, 1, tzinfo=UTC)
SERVER = ua.NodeId(ua.Int32(ObjectIds.Server))
BASE_EVENT = ua.NodeId(ua.Int32(ObjectIds.BaseEventType))
DATA_LOST = ua.StatusCode(ua.UInt32(StatusCodes.BadDataLost))
SEVERITY = {"high": 900, "medium": 500, "low": 300}


def to_us(when: datetime | None) -> int | None:
    """An OPC UA DateTime in microseconds since the Unix epoch; None when unspecified (the
    minimum DateTime, or None)."""
    if when is None:
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    if when <= ua.get_win_epoch().replace(tzinfo=UTC):
        return None
    return (when - EPOCH) // timedelta(microseconds=1)


def to_datetime(t_us: int) -> ua.DateTime:
    return EPOCH + timedelta(microseconds=t_us)


@dataclass(frozen=True)
class Historized:
    """A served variable and the signal that records it."""

    signal: str
    vtype: ua.VariantType


class CellHistory(HistoryStorageInterface):
    """asyncua's history storage, read from the cell's history (writes are the historian's:
    the save methods do nothing)."""

    def __init__(self, target: Target, cell: str):
        super().__init__(MAX_VALUES)
        self.target = target
        self.cell = cell
        self.nodes: dict[ua.NodeId, Historized] = {}
        self.event_sources: set[ua.NodeId] = set()
        self.alarm_type: ua.NodeId | None = None
        self._reader: HistoryReader | None = None
        self.reads = 0  # HistoryRead requests answered (tests, the bench)

    # -- what asyncua calls -------------------------------------------------------------------
    async def init(self) -> None:
        pass

    async def new_historized_node(self, node_id: ua.NodeId, period: timedelta | None,
                                  count: int = 0) -> None:
        pass

    async def save_node_value(self, node_id: ua.NodeId, datavalue: ua.DataValue) -> None:
        pass

    async def new_historized_event(self, source_id: ua.NodeId, evtypes: list[Any],
                                   period: timedelta | None, count: int = 0) -> None:
        pass

    async def save_event(self, event: Any) -> None:
        pass

    async def stop(self) -> None:
        reader = self._reader
        self._reader = None
        if reader is not None:
            await asyncio.to_thread(reader.store.close)

    async def read_node_history(self, node_id: ua.NodeId, start: datetime | None,
                                end: datetime | None, nb_values: int
                                ) -> tuple[list[ua.DataValue], datetime | None]:
        served = self.nodes.get(node_id)
        if served is None:
            return [], None
        self.reads += 1
        return await asyncio.to_thread(self._values, served, to_us(start), to_us(end),
                                       nb_values)

    async def read_event_history(self, source_id: ua.NodeId, start: datetime | None,
                                 end: datetime | None, nb_values: int, evfilter: Any
                                 ) -> tuple[list[UaEvent], datetime | None]:
        if source_id not in self.event_sources:
            return [], None
        self.reads += 1
        return await asyncio.to_thread(self._events, to_us(start), to_us(end), nb_values)

    # -- reading (in a worker thread) ----------------------------------------------------------
    def reader(self) -> HistoryReader:
        if self._reader is None:
            self._reader = HistoryReader(open_store(self.target, read_only=True), self.cell)
        return self._reader

    def _window(self, start: int | None, end: int | None, nb_values: int
                ) -> tuple[int, int, bool, int]:
        """(low, high, newest first, most values) of a ReadRaw request (Part 11 6.4.3):
        both times ascending (or descending when start > end); one of them with a count."""
        most = min(nb_values or MAX_VALUES, MAX_VALUES)
        if start is not None and end is not None:
            return min(start, end), max(start, end), start > end, most
        if start is not None:
            return start, 2**62, False, most
        if end is not None:
            return 0, end, True, most
        return 0, 2**62, False, most

    def _values(self, served: Historized, start: int | None, end: int | None,
                nb_values: int) -> tuple[list[ua.DataValue], datetime | None]:
        reader = self.reader()
        signal = reader.signal(served.signal)
        if signal is None:
            return [], None
        low, high, newest_first, most = self._window(start, end, nb_values)
        # (inclusive times: the store's windows are (start, end])
        samples = reader.store.samples(self.cell, served.signal, low - 1, high)
        segments = reader.segments(low, high)
        stream: list[tuple[int, Sample | None]] = [(s.t_us, s) for s in samples]
        stream += [(g.end_us + 1, None) for g in _stops(segments) if low <= g.end_us + 1 <= high]
        stream.sort(key=lambda item: item[0])
        if newest_first:
            stream.reverse()
        cont = None
        if len(stream) > most:
            cont = to_datetime(stream[most][0])
            stream = stream[:most]
        values = [self._value(signal, served.vtype, t, sample) for t, sample in stream]
        return values, cont

    @staticmethod
    def _value(signal: Signal, vtype: ua.VariantType, t_us: int,
               sample: Sample | None) -> ua.DataValue:
        stamp = to_datetime(t_us)
        if sample is None:
            return ua.DataValue(StatusCode=DATA_LOST, SourceTimestamp=stamp,
                                ServerTimestamp=stamp)
        value: Any = sample.value
        if signal.kind == BOOL:
            value = bool(value)
        elif signal.kind == ENUM:
            value = signal.text(value)
        elif signal.kind == COUNTER or vtype == ua.VariantType.UInt64:
            value = int(value)
        return ua.DataValue(ua.Variant(value, vtype), SourceTimestamp=stamp,
                            ServerTimestamp=stamp)

    def _events(self, start: int | None, end: int | None, nb_values: int
                ) -> tuple[list[UaEvent], datetime | None]:
        low, high, newest_first, most = self._window(start, end, nb_values)
        events = self.reader().events(low - 1, high)
        if newest_first:
            events.reverse()
        cont = None
        if len(events) > most:
            cont = to_datetime(events[most].t_us)
            events = events[:most]
        return [self._event(e) for e in events], cont

    def _event(self, event: Event) -> UaEvent:
        alarm = event.type == "alarm" and self.alarm_type is not None
        out = UaEvent(SERVER)
        stamp = to_datetime(event.t_us)
        out.add_property("EventId", uuid.uuid5(uuid.NAMESPACE_URL, f"{self.cell}/{event.t_us}/"
                                               f"{event.type}/{event.key}/{event.event}").bytes,
                         ua.VariantType.ByteString)
        out.add_property("EventType", self.alarm_type if alarm else BASE_EVENT,
                         ua.VariantType.NodeId)
        out.add_property("SourceNode", SERVER, ua.VariantType.NodeId)
        out.add_property("SourceName", self.cell, ua.VariantType.String)
        out.add_property("Time", stamp, ua.VariantType.DateTime)
        out.add_property("ReceiveTime", stamp, ua.VariantType.DateTime)
        message = event.text if not event.event or event.text.startswith(event.event) \
            else f"{event.event}: {event.text}"
        out.add_property("Message", ua.LocalizedText(message), ua.VariantType.LocalizedText)
        out.add_property("Severity", SEVERITY.get(event.severity, 100), ua.VariantType.UInt16)
        if alarm:
            state = str(event.data.get("state", ""))
            out.add_property("ConditionName", event.key, ua.VariantType.String)
            out.add_property("Transition", event.event, ua.VariantType.String)
            out.add_property("Priority", event.severity, ua.VariantType.String)
            out.add_property("ActiveState/Id", state.startswith("active"),
                             ua.VariantType.Boolean)
            out.add_property("AckedState/Id", state in ("active-acknowledged", "normal"),
                             ua.VariantType.Boolean)
        out.add_property("ClientUserId", event.by, ua.VariantType.String)
        return out


def _stops(segments: list[Segment]) -> list[Segment]:
    """The segments after whose end the history knows nothing until a later one starts (the
    last one is the cell's newest history, not a stop: it may be running now)."""
    return [s for s in segments
            if any(o.start_us > s.end_us for o in segments)
            and not any(o.start_us <= s.end_us + 1 <= o.end_us for o in segments if o is not s)]
