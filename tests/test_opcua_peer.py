"""An independent Python client, FreeOpcUa's python-opcua (the `opcua` package, synchronous,
threaded), against the cell's OPC UA server (asyncua).

asyncua is our server and the other tests' client: a mistake shared by the two would go
unseen there. python-opcua has its own client stack, its own binary encoding and its own
event-filter code; it finds everything by browse name (nothing is handed over from the
server object), reads live values as they follow the scans, and receives the alarm event a
stuck valve raises while it is subscribed, with the fields a SCADA shows. (node-opcua, in
tests/test_opcua_node.py, is the other independent client, where node and npm exist.)

The cell runs in virtual time, driven by the test; every wait is on what the client received
or on the server's published scan, with a deadline only as a safety net.
"""

from __future__ import annotations

import threading
import time
from datetime import UTC, datetime, timedelta

import pytest

pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
opcua = pytest.importorskip("opcua", reason="python-opcua (the [test] extra) is not installed")
from opcua import Client, ua  # noqa: E402
from opcua.common.events import get_filter_from_event_type  # noqa: E402

from hmi.opcua.server import ServeOptions  # noqa: E402
from tests.opcua_cells import serve, valve_session  # noqa: E402

WAIT_S = 120.0  # a safety net only: every wait ends on the state it waits for
CELL = "cispi_valve"
ALARM_TYPE_PATH = ["0:Types", "0:EventTypes", "0:BaseEventType", "0:ConditionType",
                   "0:AcknowledgeableConditionType", "0:AlarmConditionType"]


def until(predicate, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        assert time.monotonic() < deadline, f"waited {WAIT_S:g} s for {what}"
        time.sleep(0.01)


class Handler:
    """python-opcua's subscription handler: notifications arrive in its own thread."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.changes: list[tuple[str, object]] = []
        self.events: list[dict[str, object]] = []

    def datachange_notification(self, node, value, data) -> None:
        with self.lock:
            self.changes.append((node.nodeid.to_string(), value))

    def event_notification(self, event) -> None:
        with self.lock:
            self.events.append({name: variant.Value for name, variant
                                in event.get_event_props_as_fields_dict().items()})

    def seen(self, predicate) -> list:
        with self.lock:
            return [item for item in (*self.changes, *self.events) if predicate(item)]


def _state_clauses(ns_alarm_type) -> ua.EventFilter:
    """The filter python-opcua builds from the event type (its properties, OfType), plus the
    two-state Ids a SCADA needs to tell an active, unacknowledged alarm (python-opcua names
    a field after the first element of its browse path: ActiveState, AckedState)."""
    evfilter = get_filter_from_event_type([ns_alarm_type])
    for state in ("ActiveState", "AckedState"):
        operand = ua.SimpleAttributeOperand()
        operand.TypeDefinitionId = ua.NodeId(ua.ObjectIds.AlarmConditionType)
        operand.BrowsePath = [ua.QualifiedName(state, 0), ua.QualifiedName("Id", 0)]
        operand.AttributeId = ua.AttributeIds.Value
        evfilter.SelectClauses.append(operand)
    return evfilter


def test_python_opcua_browses_reads_live_values_and_receives_the_alarm():
    session = valve_session()  # F5 (valve stuck) at 8.2 s, diagnosed at 9.19 s
    server = serve(session, lambda port: ServeOptions(port=port))
    client = Client(server.url, timeout=WAIT_S)
    client.connect()
    try:
        ns = client.get_namespace_index(f"urn:plchmi:{CELL}")
        cell = client.get_objects_node().get_child([f"{ns}:{CELL}"])
        names = {child.get_browse_name().Name for child in cell.get_children()}
        assert {"Valve V1", "Status", "Constraints", "Alarms"} <= names
        assert "Commands" not in names  # read-only by default
        valve = cell.get_child([f"{ns}:Valve V1"])
        assert "Valve V1" in valve.get_description().Text
        fsc = valve.get_child([f"{ns}:Inputs", f"{ns}:fsc", f"{ns}:Value"])
        opened = valve.get_child([f"{ns}:Outputs", f"{ns}:O", f"{ns}:WrittenValue"])
        count = cell.get_child([f"{ns}:Status", f"{ns}:ScanCount"])
        assert fsc.get_data_type_as_variant_type() == ua.VariantType.Boolean

        handler = Handler()
        subscription = client.create_subscription(10, handler)
        subscription.subscribe_data_change([count, opened])
        alarm_type = client.get_root_node().get_child(
            [*ALARM_TYPE_PATH, f"{ns}:PlchmiAlarmType"])
        subscription.subscribe_events(client.get_node(ua.ObjectIds.Server), alarm_type,
                                      evfilter=_state_clauses(alarm_type))

        # Live values: the scan count and the valve's open order follow the scans.
        for _ in range(150):  # the valve starts opening at 1 s
            session.scan_once()
        snap = session.last
        until(lambda: server.published_scan >= snap.snapshot.scan, "the server's publish")
        count_id = count.nodeid.to_string()
        until(lambda: handler.seen(lambda c: c == (count_id, snap.snapshot.scan)),
              "the scan count's notification")
        value = count.get_data_value()
        assert value.Value.Value == snap.snapshot.scan
        stamp = server.epoch + timedelta(microseconds=snap.snapshot.time_us)
        assert _utc(value.SourceTimestamp) == stamp
        assert opened.get_value() is snap.snapshot.output_map["O"] is True
        assert fsc.get_value() is snap.snapshot.value("fsc")

        # The alarm: raised while the client is subscribed, sent with the SCADA's fields.
        while session.engine.scan < 1000:
            session.scan_once()
        alarm = next(a for a in session.last.alarms if a.key == "diagnosis:V1")
        until(lambda: handler.seen(lambda e: isinstance(e, dict)
                                   and e.get("ConditionName") == "diagnosis:V1"),
              "the alarm event")
        event = handler.seen(lambda e: isinstance(e, dict)
                             and e.get("ConditionName") == "diagnosis:V1")[0]
        assert event["Severity"] == 900 and event["Priority"] == "high"
        assert event["Message"].Text == alarm.text
        assert event["Why"] == alarm.explanation.why
        assert event["ActiveState"] is True and event["AckedState"] is False
        assert event["Retain"] is True and event["Transition"] == "raised"
        assert event["SourceName"] == "Valve V1"
        assert _utc(event["Time"]) == server.epoch + timedelta(microseconds=alarm.raised_us)
        subscription.delete()
    finally:
        client.disconnect()
        server.stop()


def _utc(stamp: datetime) -> datetime:
    """python-opcua decodes UtcTime as a naive datetime in UTC."""
    return stamp.replace(tzinfo=UTC) if stamp.tzinfo is None else stamp
