"""The protocol between the runtime and its screens (hmi/wire): the type-directed codec gives
back what it was given, and bytes from a screen become a screen's message or a WireError —
never another exception, never an object of another type; the runtime disconnects a screen
that sends garbage and goes on serving the others (fuzzed with hypothesis over its real
socket)."""

from __future__ import annotations

import json
import os
import socket
import string
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hmi.engine.commands import (
    Acknowledge,
    CommentAlarm,
    InjectFault,
    ManualOutput,
    SetMode,
    SetSpeed,
    Shelve,
    StepScans,
)
from hmi.explain.reset import ResetLine
from hmi.link.base import Identity
from hmi.project.injection import Injection
from hmi.project.kept import fingerprint
from hmi.session.view import CellView
from hmi.wire import messages as m
from hmi.wire.codec import Codec, WireError
from hmi.wire.framing import MAX_OUT, frame, read_message
from tests.conftest import PROJECTS, make_session
from tests.runtimes import runtime, wait_for

VALVE = PROJECTS / "cispi_valve"
EXAMPLES = int(os.environ.get("PLCHMI_FUZZ_EXAMPLES", "150"))


def snapshots(project, control=None, inject=(), scans=2000, commands=()):
    session = make_session(PROJECTS / project, control=control, inject=inject)
    taken = []
    for k in range(scans):
        for at, command in commands:
            if at == k:
                session.command(command)
        snap = session.scan_once()
        if k % 97 == 0 or snap.alarm_events:
            taken.append(snap)
    return session, taken


@pytest.mark.parametrize("project, control, inject", [
    ("cispi_valve", "faulty", ("F13@3s",)), ("sorting", "faulty", ()),
    ("palletizer", None, ()), ("conveyor_robot", None, ("C1.stop@1s+2s",)),
    ("cispi_subsystem", None, ("V1.F1@2s",))])
def test_every_snapshot_comes_back_as_it_was(project, control, inject):
    commands = ((300, SetMode(True)), (320, ManualOutput("O", True)) if project ==
                "cispi_valve" else (320, SetMode(False)), (400, SetMode(False)),
                (1500, Acknowledge(None)))
    session, taken = snapshots(project, control, inject, commands=commands)
    layout = session.engine.layout
    codec = m.codec(layout=lambda: layout)
    assert any(s.alarms for s in taken) or project in ("palletizer",)
    for snap in taken:
        back = codec.loads(codec.dumps(snap, CellView), CellView)
        assert back == snap
        assert back.snapshot.monitors == snap.snapshot.monitors
        assert back.snapshot.waits == snap.snapshot.waits


def test_a_frame_with_shelved_alarms_and_policies_comes_back():
    session, _ = snapshots("cispi_valve", "faulty", scans=600)
    key = session.last.alarms[0].key
    assert session.command(Shelve(key, 60_000_000)).accepted
    snap = session.scan_once()
    assert snap.shelved and any(e.policies for e in snap.explanations)
    codec = m.codec(layout=lambda: session.engine.layout)
    assert codec.loads(codec.dumps(snap, CellView), CellView) == snap


# -- a screen's bytes --------------------------------------------------------------------

CODEC = m.codec()
VALID = [
    m.Hello(m.PROTOCOL, "abc", "def", Identity("alice", "operator", "terminal", "s1"), True),
    m.Send(1, SetMode(True)), m.Send(2, ManualOutput("O", None)),
    m.Send(3, SetSpeed(None)), m.Send(4, InjectFault(Injection("F5", 3, "V1", 2))),
    m.Send(5, CommentAlarm("constraint:CSs1", "seen")),
    m.Send(6, StepScans(3), m.ResetGuard((ResetLine("x", True, "", "n", "", "N1"),), 9)),
    m.Send(7, Acknowledge(None), None, Identity("bob", door="opcua"), "note"),
    m.RequestControl(8), m.TakeControl(9), m.ReleaseControl(10), m.HandOver(11, "c2"),
    m.Advance(12, 1000), m.Query(13), m.Bye(True),
    m.Report(m.ServiceStatus("opcua", "serving", "ok", 1)),
]


@pytest.mark.parametrize("message", VALID, ids=lambda msg: type(msg).__name__)
def test_every_kind_of_screen_message_comes_back(message):
    assert CODEC.loads(CODEC.dumps(message, m.ClientMessage), m.ClientMessage) == message


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=6), inner,
                                                                  max_size=4),
    max_leaves=40)


def decoded(data: bytes):
    """A screen's message, or the WireError saying why not: nothing else may come out."""
    try:
        message = CODEC.loads(data, m.ClientMessage)
    except WireError as exc:
        return exc
    assert isinstance(message, m.ClientMessage.__args__)  # type: ignore[attr-defined]
    return message


@settings(max_examples=EXAMPLES * 4, deadline=None)
@given(json_values)
def test_any_json_is_a_message_or_a_wire_error(value):
    decoded(json.dumps(value).encode())


@settings(max_examples=EXAMPLES * 4, deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_are_a_message_or_a_wire_error(data):
    decoded(data)


def mutations(tree):
    """`tree` with one item replaced by something else, somewhere inside."""
    paths = []

    def walk(node, path):
        paths.append(path)
        if isinstance(node, list):
            for k, item in enumerate(node):
                walk(item, (*path, k))
    walk(tree, ())
    return st.tuples(st.sampled_from(paths), json_values | st.sampled_from(
        ["Send", "Hello", "Frame", "Snapshot", "Engine", "__class__", 2 ** 64, -1, 1e308,
         "x" * 1000, [], [[[[[]]]]]]))


@settings(max_examples=EXAMPLES * 4, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(VALID).flatmap(
    lambda message: st.tuples(st.just(json.loads(CODEC.dumps(message, m.ClientMessage))),
                              mutations(json.loads(CODEC.dumps(message, m.ClientMessage))))))
def test_a_valid_message_changed_anywhere_is_a_message_or_a_wire_error(case):
    tree, (path, replacement) = case
    if not path:
        tree = replacement
    else:
        node = tree
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = replacement
    decoded(json.dumps(tree).encode())


def test_deep_nesting_and_huge_numbers_are_refused_in_words():
    for data in (b"[" * 100_000 + b"]" * 100_000, b"1" + b"0" * 5000, b"NaN",
                 b'["Send", 1, ["StepScans", 1e999], null, null, ""]'):
        assert isinstance(decoded(data), WireError), data[:20]


def test_a_union_member_is_only_ever_a_class_the_type_names():
    """The tag picks among the union's members: a class of another module, however it is
    named, is not built."""
    for tag in ("Engine", "Popen", "Snapshot", "Frame", "Welcome", "object", "type"):
        assert isinstance(decoded(json.dumps(["Send", 1, [tag]]).encode()), WireError)
        assert isinstance(decoded(json.dumps([tag, 1]).encode()), WireError)


def test_the_schema_digest_changes_with_any_field():
    @dataclass(frozen=True)
    class One:
        a: int

    @dataclass(frozen=True)
    class Two:
        a: int
        b: str = ""
    assert Codec().schema_digest(One) != Codec().schema_digest(Two)
    assert m.schema_digest() == m.schema_digest()


# -- over the socket ---------------------------------------------------------------------

def raw_screen(sock_path):
    raw = socket.socket(socket.AF_UNIX)
    raw.settimeout(60)
    raw.connect(str(sock_path))
    return raw


def closed_by_runtime(raw) -> bool:
    """The runtime answered (a Refused at most) and closed this connection."""
    try:
        while True:
            read_message(raw, MAX_OUT)
    except (ConnectionError, OSError):
        return True


garbage = st.one_of(
    st.binary(min_size=1, max_size=300),
    json_values.map(lambda v: json.dumps(v).encode()),
    st.sampled_from(VALID).map(lambda msg: json.dumps(
        json.loads(CODEC.dumps(msg, m.ClientMessage))[:-1]).encode()),  # one field short
)


def test_a_malformed_message_disconnects_that_screen_only(tmp_path):
    sock = tmp_path / "data" / "fuzz" / "runtime.sock"
    journal = tmp_path / "journal.jsonl"
    with runtime(VALVE, sock, "--journal", str(journal)) as cell:
        good = cell.attach("good")
        hello = m.Hello(m.PROTOCOL, m.schema_digest(), fingerprint(VALVE, None),
                        Identity("fuzz", "operator"), False)
        sent = {"before hello": 0, "after hello": 0}

        @settings(max_examples=EXAMPLES, deadline=None,
                  suppress_health_check=[HealthCheck.too_slow,
                                         HealthCheck.function_scoped_fixture])
        @given(garbage, st.booleans(), st.sampled_from(["whole", "header", "oversize"]))
        def one_screen(data, after_hello, how):
            raw = raw_screen(sock)
            try:
                if after_hello:
                    raw.sendall(frame(CODEC.dumps(hello, m.ClientMessage)))
                    read_message(raw, MAX_OUT)  # its Welcome
                if how == "whole":
                    raw.sendall(frame(data))
                elif how == "header":
                    raw.sendall((0).to_bytes(4, "big") + data)  # an empty message
                else:
                    raw.sendall((2 ** 31).to_bytes(4, "big") + data)
                if decoded(data) is not None and not isinstance(decoded(data), WireError) \
                        and how == "whole":
                    return  # a valid message by chance: not garbage
                assert closed_by_runtime(raw)
                sent["after hello" if after_hello else "before hello"] += 1
            finally:
                raw.close()
        one_screen()
        # the good screen never noticed: it runs the cell on, its commands answered
        assert good.advance(1_000_000) == 100 and good.lost is None
        assert good.command(SetMode(True)).result.accepted
        stats = good.query()
        assert stats.clients == 1
        good.leave()
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    malformed = [e for e in entries if e.get("event") == "client-lost"
                 and "malformed" in e["message"]]
    assert len(malformed) == sent["after hello"] > 0
    assert entries[-1]["event"] == "stop"


def test_a_screen_that_sends_nothing_is_let_go(tmp_path, monkeypatch):
    """No Hello within its time: the connection is closed, nothing is attached."""
    import hmi.runtime.server as server
    sock = tmp_path / "data" / "quiet" / "runtime.sock"
    with runtime(VALVE, sock) as cell:
        raw = raw_screen(sock)
        raw.sendall(b"\x00\x00")  # half a header, then nothing
        assert closed_by_runtime(raw)  # within HELLO_S
        assert server.HELLO_S <= 10
        cell.attach().leave()


@pytest.mark.parametrize("text", ["x" * 600, "\u2028line\u2029" + string.printable])
def test_long_or_odd_comments_travel_and_are_bounded_by_the_session(text, tmp_path):
    sock = tmp_path / "data" / "c" / "runtime.sock"
    with runtime(VALVE, sock, "--control", "faulty") as cell:
        link = cell.attach()
        link.advance(5_000_000)
        key = wait_for(lambda: link.last.alarms and link.last.alarms[0].key, "an alarm")
        answer = link.command(CommentAlarm(key, text))
        assert answer.result.accepted
        link.leave()
