"""The cell's OPC UA server, seen by an asyncua client: browse, subscribe, alarms, commands.

One server for each way it reads the cell (it takes ~3 s to start): a session in this process
(``plchmi run --opcua``), or the runtime's protocol as the gateway reads it (every message
encoded and decoded as over the socket, its commands as the gateway's on behalf of its users:
hmi.link.local.LocalLink); the same tests, the same address space and Part 9 behaviour. The
session runs in virtual time: each
test drives the scans itself (session.scan_once, in a worker thread so the client's loop
keeps answering), then waits on the server's own state (the scan it last published) or on
what the client received, never on the wall clock alone.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace
from datetime import timedelta
from functools import partial
from pathlib import Path

import pytest

asyncua = pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
from asyncua import Client, ua  # noqa: E402
from asyncua.ua.uaerrors import UaStatusCodeError  # noqa: E402

from hmi.engine.commands import (  # noqa: E402
    FaultReset,
    InjectFault,
    Pause,
    RepairFaults,
    Resume,
    SetMode,
)
from hmi.explain.journal import Journal  # noqa: E402
from hmi.opcua.options import journal_refusals, server_certificate  # noqa: E402
from hmi.opcua.server import ServeOptions  # noqa: E402
from hmi.project.injection import parse_injection  # noqa: E402
from hmi.session.journal_recorder import JournalRecorder  # noqa: E402
from tests.opcua_cells import serve, trust_list, users, valve_session  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
PASSWORD = "correct horse"
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
WAIT_S = 120.0  # a safety net only: every wait ends on the state it waits for
FIRST_FAULT_US = 8_000_000  # before the F5 the plant starts with (8.2 s)


class Cell:
    def __init__(self, tmp: Path, through: str = "session"):
        self.through = through
        self.session = valve_session()
        project = self.session.engine.project
        self.journal_path = tmp / "journal.jsonl"
        self.recorder = JournalRecorder(self.session, Journal(self.journal_path))
        # alice has a password; carol a certificate the server trusts; the server has its
        # own certificate, so passwords travel encrypted and certificates can be checked.
        self.carol = _user_certificate(tmp / "carol", "carol")
        self.stranger = _user_certificate(tmp / "stranger", "stranger")
        # alice an engineer (forcing, the policy), olga an operator, victor a viewer
        known = users(tmp, {"alice": "engineer", "olga": "operator", "victor": "viewer",
                            "carol": "operator", "dave": "operator"}, PASSWORD,
                      {"carol": self.carol[0].read_bytes()})
        cert, key = server_certificate(tmp / "pki", project.name, "127.0.0.1")
        self.options = partial(ServeOptions, writable=True, users=known, certificate=cert,
                               private_key=key, trust=trust_list(tmp))

    def start(self) -> None:
        cell = self.session
        if self.through == "protocol":  # the gateway's view: a screen of the runtime
            from hmi.link.local import LocalLink
            from hmi.opcua.source import LinkSource
            from hmi.wire.messages import Identity
            self.link = LocalLink(self.session, identity=Identity("gw", "operator", "opcua",
                                                                  "gw"),
                                  journal=self.recorder)
            cell = LinkSource(self.link)
            refused = self.link.report_refusal  # the runtime journals it (the gateway's way)
        else:
            refused = journal_refusals(self.recorder)
        self.server = serve(cell, lambda port: self.options(port=port), refused=refused)

    async def scans(self, n: int) -> int:
        """Run n scans in virtual time; return once the server has published the last."""
        await asyncio.to_thread(lambda: [self.session.scan_once() for _ in range(n)])
        scan = self.session.last.snapshot.scan
        await until(lambda: self.server.published_scan >= scan)
        return scan

    async def new_fault(self) -> None:
        """The valve repaired, a fault reset, then stuck again: fresh alarms (the high
        diagnosis, latched; the constraint CSs4, transient) for a test that needs them."""
        self.session.command(RepairFaults())
        self.session.command(FaultReset())
        await self.scans(400)
        self.session.command(InjectFault(parse_injection(
            f"F5@{self.session.engine.now / 1e6 + 0.01:.2f}s")))
        await self.scans(1500)

    async def fresh_alarm(self) -> None:
        """diagnosis:V1 about to be raised, or raised again, in the scans this call runs (for a
        test that must see its event): the F5 the plant was started with while no scan has
        reached it yet, else a new fault. Each test prepares the state it needs, whichever
        tests ran before it in this process (under xdist a module's tests are spread over
        the workers, each with a server of its own)."""
        if self.session.engine.now < FIRST_FAULT_US:
            await self.scans(1000 - self.session.engine.scan)  # F5 at 8.2 s, seen at 9.19 s
        else:
            await self.new_fault()

    async def unacknowledged(self, key: str = "diagnosis:V1") -> None:
        """The alarm `key` listed and waiting for an acknowledgement."""
        if not any(a.key == key and a.state == "active-unacknowledged"
                   for a in self.alarms()):
            await self.fresh_alarm()

    def alarms(self) -> tuple:
        last = self.session.last
        return last.alarms if last is not None else ()

    def journal(self) -> list[dict]:
        return [json.loads(line) for line in self.journal_path.read_text().splitlines()]


def _user_certificate(folder: Path, name: str) -> tuple[Path, Path]:
    """A user's certificate (DER) and private key (PEM), self-signed."""
    from asyncua.crypto import cert_gen
    from cryptography.hazmat.primitives.serialization import Encoding
    from cryptography.x509.oid import ExtendedKeyUsageOID
    folder.mkdir()
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key, f"urn:test:{name}", {"commonName": name}, [],
        [ExtendedKeyUsageOID.CLIENT_AUTH])
    der, pem = folder / "cert.der", folder / "key.pem"
    der.write_bytes(cert.public_bytes(Encoding.DER))
    pem.write_bytes(cert_gen.dump_private_key_as_pem(key))
    return der, pem


async def until(predicate, what: str = "the expected state") -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError(f"waited {WAIT_S:g} s for {what}")
        await asyncio.sleep(0.01)


@pytest.fixture(scope="module", params=["session", "protocol"])
def cell(tmp_path_factory, request):
    cell = Cell(tmp_path_factory.mktemp("opcua"), request.param)
    cell.start()
    yield cell
    cell.server.stop()
    cell.recorder.close()


def client(cell: Cell, user: str | None = None, password: str = PASSWORD) -> Client:
    c = Client(cell.server.url, timeout=WAIT_S)
    if user is not None:
        c.set_user(user)
        c.set_password(password)
    return c


class Events:
    def __init__(self):
        self.events: list[dict] = []
        self.changes: list[tuple] = []

    def event_notification(self, event):
        self.events.append({k: v.Value for k, v in
                            event.get_event_props_as_fields_dict().items()})

    def datachange_notification(self, node, value, data):
        self.changes.append((node, value, data.monitored_item.Value))

    def status_change_notification(self, status):
        pass


async def _cell_node(c: Client):
    ns = await c.get_namespace_index("urn:plchmi:cispi_valve")
    return ns, await c.nodes.objects.get_child(f"{ns}:cispi_valve")


async def test_an_integrator_finds_the_cell_its_device_and_every_io_by_browsing(cell):
    async with client(cell) as c:
        ns, node = await _cell_node(c)
        children = {(await k.read_browse_name()).Name for k in await node.get_children()}
        assert {"Valve V1", "Status", "Constraints", "Alarms", "Commands"} <= children
        valve = await node.get_child(f"{ns}:Valve V1")
        text = (await valve.read_description()).Text
        assert "Valve V1" in text
        for name in ("fsc", "fso"):
            io = await valve.get_child([f"{ns}:Inputs", f"{ns}:{name}"])
            assert "end switch" in (await io.read_description()).Text
            leaves = {(await k.read_browse_name()).Name for k in await io.get_children()}
            assert {"Value", "FilteredValue", "Reconstructed"} <= leaves
        out = await valve.get_child([f"{ns}:Outputs", f"{ns}:C"])
        leaves = {(await k.read_browse_name()).Name for k in await out.get_children()}
        assert leaves == {"ProgramValue", "WrittenValue", "FilterChanged", "FilterConstraint",
                          "Masked"}
        flag = await valve.get_child([f"{ns}:Diagnosers", f"{ns}:V1", f"{ns}:Flags",
                                      f"{ns}:def_V"])
        assert await flag.read_data_type_as_variant_type() == ua.VariantType.Boolean
        scan_time = await node.get_child([f"{ns}:Status", f"{ns}:ScanTime"])
        eu = await scan_time.get_child("0:EngineeringUnits")
        units = await eu.read_value()
        assert (units.DisplayName.Text, units.UnitId) == ("ms", 4405047)
        labels = await valve.get_child([f"{ns}:Diagnosers", f"{ns}:V1", f"{ns}:Labels"])
        assert await labels.read_value_rank() == 1


async def test_values_follow_the_scans_with_the_scans_time_as_source_timestamp(cell):
    async with client(cell) as c:
        ns, node = await _cell_node(c)
        count = await node.get_child([f"{ns}:Status", f"{ns}:ScanCount"])
        written = await node.get_child([f"{ns}:Valve V1", f"{ns}:Outputs", f"{ns}:O",
                                        f"{ns}:WrittenValue"])
        handler = Events()
        sub = await c.create_subscription(10, handler)
        await sub.subscribe_data_change([count, written])
        scan = await cell.scans(150)  # the valve starts opening at 1 s
        snap = cell.session.last
        await until(lambda: any(v == scan for n, v, _ in handler.changes if n == count),
                    "the last scan count")
        value = await count.read_data_value()
        assert value.Value.Value == snap.snapshot.scan
        epoch = cell.server.epoch
        assert value.SourceTimestamp == epoch + timedelta(microseconds=snap.snapshot.time_us)
        assert await written.read_value() == snap.snapshot.output_map["O"]
        opened = [(v, dv.SourceTimestamp) for n, v, dv in handler.changes if n == written]
        assert opened[-1][0] is snap.snapshot.output_map["O"]
        await sub.delete()


async def test_an_injected_fault_raises_a_high_alarm_event_with_its_explanation(cell):
    async with client(cell) as c:
        handler = Events()
        sub = await c.create_subscription(10, handler)
        await sub.subscribe_events(c.nodes.server,
                                   c.get_node(cell.server.alarm_type.nodeid))
        await cell.fresh_alarm()
        alarm = next(a for a in cell.session.last.alarms if a.key == "diagnosis:V1")
        await until(lambda: any(e["ConditionName"] == "diagnosis:V1" and e["ActiveState/Id"]
                                for e in handler.events), "the alarm event")
        # the last one: a new fault (fresh_alarm) sends the older alarm's end before it
        event = next(e for e in reversed(handler.events)
                     if e["ConditionName"] == "diagnosis:V1" and e["ActiveState/Id"])
        assert event["Severity"] == 900 and event["Priority"] == "high"
        assert event["Message"].Text == alarm.text
        assert event["Why"] == alarm.explanation.why
        assert event["Consequences"] == alarm.explanation.consequences
        assert event["Policies"] == alarm.explanation.policies_text()
        assert event["Detail"] == getattr(alarm.explanation, "detail", "")
        assert event["ActiveState/Id"] is True and event["AckedState/Id"] is False
        assert event["Retain"] is True
        assert event["SourceName"] == "Valve V1"
        assert event["ConditionClassId"] == ua.NodeId(ua.ObjectIds.ProcessConditionClassType)
        when = cell.server.epoch + timedelta(microseconds=alarm.changed_us)  # raised or back
        assert event["Time"] == when
        await sub.delete()


async def test_acknowledge_goes_through_the_session_and_is_journalled_with_the_user(cell):
    await cell.unacknowledged("diagnosis:V1")
    before = len(cell.journal())
    async with client(cell, "alice") as c:
        handler = Events()
        sub = await c.create_subscription(10, handler)
        await sub.subscribe_events(c.nodes.server,
                                   c.get_node(cell.server.alarm_type.nodeid))
        # ConditionRefresh (on the ConditionType) replays the retained conditions.
        await c.get_node(ua.ObjectIds.ConditionType).call_method(
            ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
            ua.Variant(sub.subscription_id, ua.VariantType.UInt32))
        await until(lambda: any(e.get("ConditionName") == "diagnosis:V1"
                                for e in handler.events), "the refreshed condition")
        event = next(e for e in handler.events if e.get("ConditionName") == "diagnosis:V1")
        condition = c.get_node(event["NodeId"])
        await condition.call_method(ACK, ua.Variant(event["EventId"], ua.VariantType.ByteString),
                                    ua.LocalizedText("checking the valve"))
        await cell.scans(1)
        await until(lambda: any(e.get("ConditionName") == "diagnosis:V1"
                                and e.get("AckedState/Id") for e in handler.events),
                    "the acknowledged condition")
        acked = next(e for e in handler.events if e.get("ConditionName") == "diagnosis:V1"
                     and e.get("AckedState/Id"))
        assert acked["ClientUserId"] == "alice"
        assert acked["Comment"].Text == "checking the valve"
        assert acked["ActiveState/Id"] is True and acked["Retain"] is True
        await sub.delete()
    state = next(a.state for a in cell.session.alarms.listed() if a.key == "diagnosis:V1")
    assert state == "active-acknowledged"
    entries = cell.journal()[before:]
    action = next(e for e in entries if e.get("event") == "acknowledge alarm diagnosis:V1")
    assert action["accepted"] is True
    assert action["by"] == "opcua:alice (checking the valve)"
    ack = next(e for e in entries if e["type"] == "alarm" and e["event"] == "acknowledged"
               and e["key"] == "diagnosis:V1")
    assert ack["by"] == action["by"]


async def test_an_anonymous_client_reads_but_cannot_acknowledge_command_or_write(cell):
    await cell.unacknowledged("diagnosis:V1")  # a condition to try acknowledging
    before = len(cell.journal())
    async with client(cell) as c:
        ns, node = await _cell_node(c)
        reset = await node.get_child([f"{ns}:Commands", f"{ns}:FaultReset"])
        commands = await node.get_child(f"{ns}:Commands")
        with pytest.raises(UaStatusCodeError, match="BadUserAccessDenied"):
            await commands.call_method(reset)
        mode = await node.get_child([f"{ns}:Status", f"{ns}:Mode"])
        with pytest.raises(UaStatusCodeError, match=r"BadUserAccessDenied|BadNotWritable"):
            await mode.write_value("manual")
        alarms = await node.get_child(f"{ns}:Alarms")
        condition = (await alarms.get_children())[0]
        with pytest.raises(UaStatusCodeError, match="BadUserAccessDenied"):
            await condition.call_method(ACK, ua.Variant(b"x", ua.VariantType.ByteString),
                                        ua.LocalizedText(""))
    assert len(cell.journal()) == before, "a refused client left a trace as an action"
    assert cell.session.engine.mode == "auto"


async def test_a_wrong_password_is_refused_at_the_door_and_journalled(cell):
    before = len(cell.journal())
    with pytest.raises(UaStatusCodeError, match=r"BadUserAccessDenied|BadIdentityToken"):
        async with client(cell, "alice", "not the password"):
            pass
    with pytest.raises(UaStatusCodeError, match=r"BadUserAccessDenied|BadIdentityToken"):
        async with client(cell, "mallory", PASSWORD):
            pass
    refused = [e for e in cell.journal()[before:] if e["event"] == "sign-in-refused"]
    assert [e["by"] for e in refused] == ["opcua:alice", "opcua:mallory"]
    for entry in refused:
        assert entry["source"].startswith("127.0.0.1:") and entry["door"] == "opcua"
        assert "wrong user name or password" in entry["message"]
        assert "not the password" not in json.dumps(entry)


async def test_the_attempt_that_locks_an_account_is_journalled(cell):
    before = len(cell.journal())
    for _ in range(5):
        with pytest.raises(UaStatusCodeError, match=r"BadUserAccessDenied|BadIdentityToken"):
            async with client(cell, "dave", "guessing wrong"):
                pass
    with pytest.raises(UaStatusCodeError, match=r"BadUserAccessDenied|BadIdentityToken"):
        async with client(cell, "dave", PASSWORD):  # the right one, now locked
            pass
    events = [(e["event"], e["by"]) for e in cell.journal()[before:]
              if e["event"] in ("sign-in-refused", "account-locked")]
    assert events == [("sign-in-refused", "opcua:dave")] * 4 + [
        ("account-locked", "opcua:dave"), ("sign-in-refused", "opcua:dave")]
    assert "locked" in cell.journal()[-1]["message"]


async def test_operator_commands_are_methods_that_go_through_the_filter(cell):
    await cell.scans(1)
    if "O" not in cell.session.last.snapshot.masked:  # the diagnoser distrusts the valve (F5)
        await cell.fresh_alarm()
    assert "O" in cell.session.last.snapshot.masked
    async with client(cell, "alice") as c:
        ns, node = await _cell_node(c)
        commands = await node.get_child(f"{ns}:Commands")

        async def call(name, *args):
            method = await commands.get_child(f"{ns}:{name}")
            return await commands.call_method(method, *args)

        try:
            accepted, message = await call("SetMode", True)
            assert accepted, message
            assert cell.session.engine.mode == "manual"
            accepted, message = await call("ManualOutput", "O", "sideways")
            assert not accepted and "on, off or release" in message
            accepted, message = await call("ManualOutput", "nope", "on")
            assert not accepted
            accepted, message = await call("ManualOutput", "O", "on")
            assert accepted, message
            await cell.scans(2)
            # The diagnoser distrusts the valve (F5): the filter masks the open order.
            snap = cell.session.last
            assert snap.snapshot.fov_map["O"] is True and snap.snapshot.output_map["O"] is False
            written = await node.get_child([f"{ns}:Valve V1", f"{ns}:Outputs", f"{ns}:O"])
            assert await (await written.get_child(f"{ns}:WrittenValue")).read_value() is False
            assert await (await written.get_child(f"{ns}:Masked")).read_value() is True
            accepted, message = await call("SetMode", False)
            assert accepted
        finally:  # the next test finds the cell in automatic mode, whatever failed here
            if cell.session.engine.mode == "manual":
                cell.session.command(SetMode(False))
    entries = [e for e in cell.journal() if e.get("by") == "opcua:alice"]
    events = [e["event"] for e in entries]
    assert {"enter manual mode", "manual O on", "leave manual mode"} <= set(events)
    refused = [e for e in entries if e["event"] == "manual nope on"]
    assert refused and refused[0]["accepted"] is False
    result = next(e for e in cell.journal() if e["event"] == "manual O on: filter result")
    assert result["message"].startswith("refused") and result["by"] == "opcua:alice"


async def test_a_trusted_user_certificate_names_the_user_an_unknown_one_does_not(cell):
    async def reset_as(certificate: tuple[Path, Path]):
        c = client(cell)
        await c.load_client_certificate(str(certificate[0]))
        await c.load_private_key(str(certificate[1]))
        async with c:
            ns, node = await _cell_node(c)
            commands = await node.get_child(f"{ns}:Commands")
            return await commands.call_method(await commands.get_child(f"{ns}:FaultReset"))

    accepted, message = await reset_as(cell.carol)
    assert accepted, message
    entry = cell.journal()[-1]
    assert (entry["event"], entry["by"]) == ("fault reset", "opcua:carol")
    with pytest.raises(UaStatusCodeError, match="BadUserAccessDenied"):
        await reset_as(cell.stranger)  # an untrusted certificate: refused at activation
    refused = cell.journal()[-1]  # journalled as a refused sign-in, no action
    assert refused["event"] == "sign-in-refused" and refused["door"] == "opcua"
    assert "an untrusted user certificate" in refused["message"]
    assert [e for e in cell.journal() if e["type"] == "action"][-1] == entry


async def test_a_paused_cell_says_so_though_no_scan_comes(cell):
    async with client(cell) as c:
        ns, node = await _cell_node(c)
        state = await node.get_child([f"{ns}:Status", f"{ns}:RunState"])
        assert await state.read_value() == "running"
        cell.session.command(Pause())
        try:
            await until_value(state, "paused")
        finally:
            cell.session.command(Resume())
        await until_value(state, "running")


async def until_value(node, expected) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while (value := await node.read_value()) != expected:
        assert loop.time() < deadline, f"{node} stayed {value!r}, not {expected!r}"
        await asyncio.sleep(0.01)


async def test_inputs_are_uncertain_while_the_plant_does_not_answer(cell):
    """The publisher marks what comes from the plant when the snapshot says the link is lost
    (a real plant's; fed here as such a snapshot)."""
    async with client(cell) as c:
        ns, node = await _cell_node(c)
        value = await node.get_child([f"{ns}:Valve V1", f"{ns}:Inputs", f"{ns}:fsc",
                                      f"{ns}:Value"])
        mode = await node.get_child([f"{ns}:Status", f"{ns}:Mode"])
        await cell.scans(1)
        last = cell.session.last
        lost_snap = last.snapshot._replace(scan=last.snapshot.scan + 1,
                                           plant=replace(last.snapshot.plant, connected=False))
        lost = last._replace(snapshot=lost_snap)
        for listener in list(cell.session.scan_listeners):  # as if the session scanned it
            listener(lost)
        await until(lambda: cell.server.published_scan == lost_snap.scan)
        read = await value.read_data_value(raise_on_bad_status=False)
        assert read.StatusCode.value == ua.StatusCodes.UncertainNoCommunicationLastUsableValue
        assert read.Value.Value == lost_snap.value("fsc")
        assert (await mode.read_data_value()).StatusCode.is_good()  # the cell's own: good
        await cell.scans(2)  # connected again (past the scan number the fake one took)
        assert (await value.read_data_value()).StatusCode.is_good()


async def test_acknowledge_all_as_a_command_names_the_user_in_every_condition_event(cell):
    await cell.scans(1)
    if not any(a.state == "active-unacknowledged" for a in cell.session.last.alarms):
        await cell.new_fault()
    waiting = {a.key for a in cell.session.last.alarms if a.state == "active-unacknowledged"}
    assert waiting, "no alarm waits for an acknowledgement"
    async with client(cell, "alice") as c:
        handler = Events()
        sub = await c.create_subscription(10, handler)
        await sub.subscribe_events(c.nodes.server,
                                   c.get_node(cell.server.alarm_type.nodeid))
        ns, node = await _cell_node(c)
        commands = await node.get_child(f"{ns}:Commands")
        accepted, message = await commands.call_method(
            await commands.get_child(f"{ns}:Acknowledge"), "")
        assert accepted, message
        await cell.scans(1)
        await until(lambda: waiting <= {e["ConditionName"] for e in handler.events
                                        if e.get("Transition") == "acknowledged"},
                    "the acknowledgements")
        for event in handler.events:
            if event.get("Transition") == "acknowledged":
                assert event["ClientUserId"] == "alice", event["ConditionName"]
        await sub.delete()


async def test_part9_shelving_and_comments_are_the_hmis_journalled_with_the_user(cell):
    await cell.new_fault()
    keys = {a.key: a for a in cell.session.last.alarms}
    assert {"diagnosis:V1", "constraint:CSs4"} <= set(keys)
    async with client(cell, "alice") as c:
        handler = Events()
        sub = await c.create_subscription(10, handler)
        await sub.subscribe_events(c.nodes.server,
                                   c.get_node(cell.server.alarm_type.nodeid))
        ns, node = await _cell_node(c)
        alarms = await node.get_child(f"{ns}:Alarms")

        async def shelving(key: str, method: int, *args):
            state = await alarms.get_child([f"{ns}:{key}", "0:ShelvingState"])
            return await state.call_method(ua.NodeId(method), *args)

        timed = ua.ObjectIds.ShelvedStateMachineType_TimedShelve
        await shelving("constraint:CSs4", timed, ua.Variant(60_000.0, ua.VariantType.Double))
        assert "constraint:CSs4" in cell.session.alarms.shelved
        await cell.scans(1)
        await until(lambda: any(e.get("ConditionName") == "constraint:CSs4"
                                and e.get("SuppressedOrShelved") for e in handler.events),
                    "the shelved condition")
        shelved = next(e for e in handler.events if e.get("ConditionName") ==
                       "constraint:CSs4" and e.get("SuppressedOrShelved"))
        assert shelved["ShelvingState/CurrentState"].Text == "TimedShelved"
        assert 0 < shelved["ShelvingState/UnshelveTime"] <= 60_000
        assert shelved["Retain"] is True and shelved["Transition"] == "shelved"
        with pytest.raises(UaStatusCodeError, match="BadConditionAlreadyShelved"):
            await shelving("constraint:CSs4", timed,
                           ua.Variant(1000.0, ua.VariantType.Double))
        with pytest.raises(UaStatusCodeError, match="BadShelvingTimeOutOfRange"):
            await shelving("diagnosis:V1", timed, ua.Variant(9 * 3.6e6, ua.VariantType.Double))
        with pytest.raises(UaStatusCodeError, match="BadInvalidState"):  # latched: never hidden
            await shelving("diagnosis:V1", ua.ObjectIds.ShelvedStateMachineType_OneShotShelve)
        unshelve = ua.ObjectIds.ShelvedStateMachineType_Unshelve
        await shelving("constraint:CSs4", unshelve)
        with pytest.raises(UaStatusCodeError, match="BadConditionNotShelved"):
            await shelving("constraint:CSs4", unshelve)
        await cell.scans(1)
        await until(lambda: any(e.get("ConditionName") == "constraint:CSs4"
                                and e.get("Transition") == "unshelved"
                                for e in handler.events), "the unshelved condition")
        await c.get_node(ua.ObjectIds.ConditionType).call_method(
            ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
            ua.Variant(sub.subscription_id, ua.VariantType.UInt32))
        await until(lambda: any(e.get("ConditionName") == "diagnosis:V1"
                                for e in handler.events), "the refreshed high alarm")
        high = next(e for e in reversed(handler.events)
                    if e.get("ConditionName") == "diagnosis:V1")
        condition = c.get_node(high["NodeId"])
        await condition.call_method(ua.NodeId(ua.ObjectIds.ConditionType_AddComment),
                                    ua.Variant(high["EventId"], ua.VariantType.ByteString),
                                    ua.LocalizedText("valve jammed, fitter called"))
        await sub.delete()
    entries = [e for e in cell.journal() if e.get("by") == "opcua:alice"]
    events = [(e["event"], e["accepted"]) for e in entries if e["type"] == "action"]
    assert ("shelve alarm constraint:CSs4 for 1m", True) in events
    assert ("shelve alarm diagnosis:V1 once (until it clears)", False) in events
    assert ("unshelve alarm constraint:CSs4", True) in events
    assert ("comment on alarm diagnosis:V1", True) in events
    assert any(e.get("message") == "valve jammed, fitter called" for e in cell.journal()
               if e["type"] == "alarm")
