"""OPC UA HistoryRead (Part 11) from the cell's history, read by two clients: asyncua, and
FreeOpcUa's python-opcua (its own client stack and encoding: an independent peer).

The valve runs in virtual time with F5 (stuck) at 8.2 s, its alarm acknowledged, then a
second session after a stop (two segments), all recorded by the historian into SQLite, and
again into a real PostgreSQL; a server serves the second session with that history. Every
answer is compared with the store itself: the same samples at the same instants
(SourceTimestamp), in the variable's own type, paged by continuation points, newest first
when asked, the stop between the sessions marked BadDataLost; the alarms and actions as
events.
"""

from __future__ import annotations

import asyncio
import uuid
from datetime import UTC, datetime, timedelta

import pytest

pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
opcua = pytest.importorskip("opcua", reason="python-opcua (the [test] extra) is not installed")
from asyncua import Client as AsyncClient  # noqa: E402
from asyncua import ua as aua  # noqa: E402
from opcua import Client, ua  # noqa: E402

from hmi.engine.commands import Acknowledge  # noqa: E402
from hmi.history.historian import Historian  # noqa: E402
from hmi.history.query import HistoryReader  # noqa: E402
from hmi.history.target import Target, open_store  # noqa: E402
from hmi.opcua.server import ServeOptions  # noqa: E402
from hmi.session.runio import open_journal  # noqa: E402
from tests.opcua_cells import serve, valve_session  # noqa: E402

CELL = "cispi_valve"
EPOCH = 1_790_000_000_000_000
SECOND_SESSION = EPOCH + 600_000_000  # ten minutes later
UNIX = datetime(1970, 1, 1, tzinfo=UTC)


def _record(session, target: Target, folder, seconds: float, acknowledge_at: float | None):
    journal = open_journal(session, folder / f"journal-{session.epoch_us}.jsonl", "test")
    historian = Historian(session, target, journal=journal, flush_s=0.05).attach()
    if acknowledge_at is None:
        session.run_for(int(seconds * 1e6))
    else:
        session.run_for(int(acknowledge_at * 1e6))
        session.command(Acknowledge(None))
        session.run_for(int((seconds - acknowledge_at) * 1e6))
    assert historian.flush()
    return journal, historian


@pytest.fixture(scope="module", params=[
    "sqlite", pytest.param("postgresql", marks=pytest.mark.xdist_group("postgres"))])
def served(request, tmp_path_factory):
    """The history in SQLite, then in a real PostgreSQL (a throwaway cluster): the server
    reads either through the same store API."""
    folder = tmp_path_factory.mktemp("opcua-history")
    if request.param == "sqlite":
        target = Target("sqlite", str(folder / "history.sqlite"))
    else:
        cluster = request.getfixturevalue("postgres")
        target = Target("postgresql", cluster.database(f"opcua_{uuid.uuid4().hex[:8]}"))
    first = valve_session()
    first.epoch_us = EPOCH
    journal, historian = _record(first, target, folder, 40, acknowledge_at=20)
    journal.close()
    historian.close()
    session = valve_session(())
    session.epoch_us = SECOND_SESSION
    journal, historian = _record(session, target, folder, 30, None)
    server = serve(session, lambda port: ServeOptions(port=port), history=target)
    reader = HistoryReader(open_store(target, read_only=True), CELL)
    yield server, reader, session
    server.stop()
    journal.close()
    historian.close()


def _utc(stamp: datetime) -> datetime:
    return stamp.replace(tzinfo=UTC) if stamp.tzinfo is None else stamp


def _us(stamp: datetime) -> int:
    return (_utc(stamp) - UNIX) // timedelta(microseconds=1)


def _when(t_us: int) -> datetime:
    return UNIX + timedelta(microseconds=t_us)


def _node(client: Client, *path: str):
    ns = client.get_namespace_index(f"urn:plchmi:{CELL}")
    cell = client.get_objects_node().get_child([f"{ns}:{CELL}"])
    return cell.get_child([f"{ns}:{p}" for p in path])


def test_python_opcua_reads_the_history_the_store_holds(served):
    server, reader, _ = served
    client = Client(server.url, timeout=30)
    client.connect()
    try:
        start, end = EPOCH, SECOND_SESSION + 30_000_000
        for path, name, convert in (
                (("Valve V1", "Inputs", "fso", "Value"), "fso", bool),
                (("Valve V1", "Outputs", "O", "WrittenValue"), "O", bool),
                (("Valve V1", "Outputs", "C", "ProgramValue"), "C.fov", bool),
                (("Valve V1", "Diagnosers", "V1", "State"), "V1.state", None),
                (("Status", "Mode"), "cell.mode", None),
                (("Constraints", "CSs1"), "CSs1", bool)):
            node = _node(client, *path)
            assert node.get_attribute(ua.AttributeIds.Historizing).Value.Value is True
            assert node.get_attribute(ua.AttributeIds.AccessLevel).Value.Value & \
                ua.AccessLevel.HistoryRead.mask
            values = node.read_raw_history(_when(start), _when(end))
            signal = reader.signal(name)
            stored = reader.store.samples(CELL, name, start - 1, end)
            good = [v for v in values if v.StatusCode.is_good()]
            assert [_us(v.SourceTimestamp) for v in good] == [s.t_us for s in stored], name
            expected = [convert(s.value) if convert else signal.text(s.value) for s in stored]
            assert [v.Value.Value for v in good] == expected, name
            # the stop between the two sessions: said, not bridged
            lost = [v for v in values if not v.StatusCode.is_good()]
            assert len(lost) == 1 and lost[0].StatusCode.name == "BadDataLost"
            first_end = reader.segments(EPOCH, EPOCH)[0].end_us
            assert _us(lost[0].SourceTimestamp) == first_end + 1
        states = _node(client, "Valve V1", "Diagnosers", "V1", "State").read_raw_history(
            _when(start), _when(end))
        assert {v.Value.Value for v in states if v.StatusCode.is_good()} >= {"N1", "N2"}
    finally:
        client.disconnect()


def test_python_opcua_reads_the_alarms_and_actions(served):
    server, reader, _ = served
    client = Client(server.url, timeout=30)
    client.connect()
    try:
        ns = client.get_namespace_index(f"urn:plchmi:{CELL}")
        alarm_type = client.get_root_node().get_child(
            ["0:Types", "0:EventTypes", "0:BaseEventType", "0:ConditionType",
             "0:AcknowledgeableConditionType", "0:AlarmConditionType",
             f"{ns}:PlchmiAlarmType"])
        server_node = client.get_node(ua.ObjectIds.Server)
        # (python-opcua's EventNotifier holds bit numbers: HistoryRead is bit 2, mask 4)
        assert server_node.get_attribute(ua.AttributeIds.EventNotifier).Value.Value & \
            (1 << ua.EventNotifier.HistoryRead)
        events = server_node.read_event_history(_when(EPOCH), _when(SECOND_SESSION + 60e6),
                                                0, [alarm_type])
        stored = reader.events(EPOCH - 1, SECOND_SESSION + 60_000_000)
        assert len(events) == len(stored)
        fields = [e.get_event_props_as_fields_dict() for e in events]
        by_time = [(_us(f["Time"].Value), f["Message"].Value.Text) for f in fields]
        assert [t for t, _ in by_time] == [e.t_us for e in stored]
        alarms = [f for f in fields if f["ConditionName"].Value == "diagnosis:V1"]
        assert [f["Transition"].Value for f in alarms][:2] == ["raised", "acknowledged"]
        assert alarms[0]["Severity"].Value == 900
        assert alarms[0]["Priority"].Value == "high"
        assert alarms[0]["SourceName"].Value == CELL
        actions = [f for f in fields if f["EventType"].Value == ua.NodeId(
            ua.ObjectIds.BaseEventType)]
        assert any("acknowledge" in f["Message"].Value.Text for f in actions)
    finally:
        client.disconnect()


async def test_asyncua_pages_by_continuation_points_and_reads_backwards(served):
    server, reader, _ = served
    async with AsyncClient(server.url, timeout=30) as client:
        ns = await client.get_namespace_index(f"urn:plchmi:{CELL}")
        node = await client.nodes.objects.get_child(
            [f"{ns}:{CELL}", f"{ns}:Valve V1", f"{ns}:Inputs", f"{ns}:fsc", f"{ns}:Value"])
        start, end = SECOND_SESSION, SECOND_SESSION + 30_000_000
        stored = reader.store.samples(CELL, "fsc", start - 1, end)
        assert len(stored) > 6
        details = aua.ReadRawModifiedDetails(IsReadModified=False, StartTime=_when(start),
                                             EndTime=_when(end), NumValuesPerNode=2,
                                             ReturnBounds=False)
        pages, point = [], None
        while True:
            result = await node.history_read(details, point)
            pages.append(result.HistoryData.DataValues)
            point = result.ContinuationPoint
            if point is None:
                break
        assert all(len(page) <= 2 for page in pages) and len(pages) > 2
        got = [(_us(v.SourceTimestamp), v.Value.Value) for page in pages for v in page]
        assert got == [(s.t_us, bool(s.value)) for s in stored]
        backwards = await node.read_raw_history(_when(end), _when(start))
        assert [(_us(v.SourceTimestamp), v.Value.Value) for v in backwards] == got[::-1]


async def test_a_server_without_history_says_no_data():
    session = valve_session(())
    session.scan_once()
    server = serve(session, lambda port: ServeOptions(port=port))
    try:
        async with AsyncClient(server.url, timeout=30) as client:
            ns = await client.get_namespace_index(f"urn:plchmi:{CELL}")
            node = await client.nodes.objects.get_child(
                [f"{ns}:{CELL}", f"{ns}:Valve V1", f"{ns}:Inputs", f"{ns}:fsc", f"{ns}:Value"])
            historizing = await node.read_attribute(aua.AttributeIds.Historizing)
            assert historizing.Value.Value is False
            values = await asyncio.wait_for(node.read_raw_history(_when(EPOCH),
                                                                  _when(EPOCH + 10**7)), 30)
            assert values == []
    finally:
        server.stop()
