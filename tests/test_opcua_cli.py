"""--opcua on the command line: options checked up front, the install hint, the password
file, writes refused on a real plant, and a headless served run seen by a client."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from hmi.cli import main

ROOT = Path(__file__).resolve().parent.parent
VALVE = str(ROOT / "projects" / "cispi_valve")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(autouse=True)
def data_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path / "data"))


def test_without_asyncua_the_hmi_says_how_to_install_it(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "asyncua", None)  # import asyncua -> ImportError
    for argv in ([VALVE, "--opcua"], ["run", VALVE, "--opcua", "opc.tcp://127.0.0.1:4841"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "asyncua is not installed" in err and "pip install 'plchmi[opcua]'" in err
        assert "Traceback" not in err


@pytest.mark.parametrize(("argv", "expected"), [
    (["--opcua", "http://127.0.0.1:4840"], "expected opc.tcp://HOST:PORT"),
    (["--opcua", "opc.tcp://127.0.0.1:99999"], "is not a TCP port"),
    (["--opcua-writable"], "--opcua-writable without --opcua"),
    (["--opcua", "--opcua-writable"], "--opcua-writable needs users"),
    (["--opcua", "--opcua-cert", "x.der"], "--opcua-cert and --opcua-key go together"),
    # Checked once asyncua is known to be there:
    (["--opcua", "--opcua-interval", "fast"], "--opcua-interval 'fast'"),
    (["--opcua", "--opcua-users", "/nonexistent/users"], "no such users file"),
])
def test_bad_opcua_options_are_usage_errors(argv, expected, capsys):
    if "--opcua-interval" in argv or "--opcua-users" in argv:
        pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
    assert main(["run", VALVE, "--for", "1s", *argv]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err


def test_the_trust_list_refuses_and_keeps_unknown_applications(tmp_path, capsys):
    """plchmi opcua trust puts a client application's certificate in the machine's trust
    list (and takes it out of the rejected folder); an unknown one is kept for review."""
    pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
    from hmi.opcua.options import server_certificate
    from hmi.opcua.users import TrustList, certificate_der
    cert, _ = server_certificate(tmp_path / "client", "some-client", "127.0.0.1")
    der = certificate_der(cert, "")
    trust = TrustList()  # the data folder's (PLCHMI_DATA: this test's own)
    assert not trust.check(der)
    rejected = list(trust.rejected_folder.iterdir())
    assert len(rejected) == 1 and rejected[0].read_bytes() == der
    assert main(["opcua", "trust", str(rejected[0])]) == 0
    assert "Trusted" in capsys.readouterr().out
    assert trust.check(der) and not list(trust.rejected_folder.iterdir())
    assert main(["opcua", "list"]) == 0
    assert rejected[0].name in capsys.readouterr().out
    (tmp_path / "junk.der").write_bytes(b"not a certificate")
    assert main(["opcua", "trust", str(tmp_path / "junk.der")]) == 2
    assert "not an X.509 certificate" in capsys.readouterr().err


class _Lines:
    def __init__(self, text: str):
        self.lines = text.splitlines(keepends=True)

    def readline(self) -> str:
        return self.lines.pop(0) if self.lines else ""


def test_writes_are_refused_on_a_real_plant_unless_allowed(tmp_path, capsys):
    pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
    users = tmp_path / "users"
    from hmi.access.users import add
    add(users, "alice", "operator", "long enough")
    port = _free_port()  # nobody listens there: the refusal comes before any connection
    argv = ["run", VALVE, "--for", "1s", "--plant", f"modbus://127.0.0.1:{port}",
            "--opcua", f"opc.tcp://127.0.0.1:{_free_port()}", "--opcua-writable",
            "--opcua-users", str(users), "--connect-timeout", "1s"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--opcua-writable on a real plant" in err and "--opcua-allow-real-plant" in err


async def _read_served(url: str) -> dict:
    from asyncua import Client, ua
    from asyncua.ua.uaerrors import UaStatusCodeError
    async with Client(url, timeout=30) as c:
        ns = await c.get_namespace_index("urn:plchmi:cispi_valve")
        cell = await c.nodes.objects.get_child(f"{ns}:cispi_valve")
        names = {(await k.read_browse_name()).Name for k in await cell.get_children()}
        count = await cell.get_child([f"{ns}:Status", f"{ns}:ScanCount"])
        for _ in range(3000):  # until the run published its first scan's values (before
            # that the server answers BadWaitingForInitialData, as Part 8 asks)
            value = await count.read_data_value(raise_on_bad_status=False)
            if value.StatusCode.is_good():
                break
            await asyncio.sleep(0.01)
        first = await count.read_value()
        later = first
        for _ in range(3000):  # the run scans in real time: wait for it to move on
            later = await count.read_value()
            if later > first:
                break
            await asyncio.sleep(0.01)
        refused = ""
        try:
            await c.get_node(cell.nodeid).call_method(
                ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                ua.Variant(b"x", ua.VariantType.ByteString), ua.LocalizedText(""))
        except UaStatusCodeError as exc:
            refused = type(exc).__name__
        return {"names": names, "first": first, "later": later, "refused": refused}


def test_a_headless_run_serves_the_cell_read_only_until_terminated(tmp_path):
    pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
    url = f"opc.tcp://127.0.0.1:{_free_port()}"
    env = {**os.environ, "PLCHMI_DATA": str(tmp_path / "data")}
    proc = subprocess.Popen([sys.executable, "-m", "hmi.cli", "run", VALVE, "--opcua", url],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, cwd=ROOT)
    try:
        line = proc.stderr.readline()  # printed once the server listens
        assert f"serving cispi_valve over OPC UA at {url}" in line, line
        seen = asyncio.run(_read_served(url))
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "Commands" not in seen["names"] and "Valve V1" in seen["names"]
    assert seen["later"] > seen["first"]
    assert seen["refused"] == "BadUserAccessDenied"
    assert "Ran cispi_valve" in out and "Journal:" in out
    journal = (tmp_path / "data" / "cispi_valve" / "journal.jsonl").read_text()
    assert '"event":"stop"' in journal
    served = [json.loads(line) for line in journal.splitlines() if '"opcua-' in line]
    assert [e["event"] for e in served] == ["opcua-serving", "opcua-stopped"]
    assert f"serving over OPC UA at {url}, read only" in served[0]["message"]


def test_the_journal_says_which_opcua_user_sent_a_command(tmp_path, capsys):
    from hmi.explain.journal import Journal
    path = tmp_path / "journal.jsonl"
    journal = Journal(path)
    journal.append({"type": "action", "event": "fault reset", "accepted": True,
                    "message": "reset", "scan": 3, "t": "0.030", "by": "opcua:alice"})
    journal.close()
    assert main(["journal", VALVE, "--path", str(path)]) == 0
    assert "fault reset: reset [by opcua:alice]" in capsys.readouterr().out


def test_an_address_already_in_use_is_a_usage_error(capsys):
    pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["run", VALVE, "--for", "1s", "--opcua", f"opc.tcp://127.0.0.1:{port}"]
                    ) == 2
    err = capsys.readouterr().err
    assert f"opc.tcp://127.0.0.1:{port}: cannot listen there" in err
    assert "Traceback" not in err
    # it never served: the journal says nothing of a server that stopped
    journal = Path(os.environ["PLCHMI_DATA"]) / "cispi_valve" / "journal.jsonl"
    assert journal.is_file() and '"opcua-' not in journal.read_text()
