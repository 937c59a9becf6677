"""The browser door without a browser (tests/test_web_browser.py has the real one): the
sign-in page, its cookie, who may open the screens' websocket, sign-out, the idle end of a
session, and ``plchmi web``'s refusals. A real aiohttp server on a real socket, a real users
file; the tabs' screen processes are not started here."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import aiohttp
import pytest
from aiohttp.test_utils import TestServer

from hmi.access import users
from hmi.cli import main
from hmi.web.server import COOKIE, WebDoor
from tests.conftest import PROJECTS

VALVE = PROJECTS / "cispi_valve"


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def users_path() -> Path:
    path = Path(os.environ["PLCHMI_DATA"]) / "users"
    users.add(path, "alice", "operator", "alice-password")
    path.write_text("banner = Authorised staff only\nidle-lock = 5m\n" + path.read_text())
    return path


async def started(door: WebDoor) -> TestServer:
    server = TestServer(door.app(), host="127.0.0.1", port=0)
    await server.start_server()
    return server


async def test_sign_in_cookie_screens_and_sign_out(users_path):
    clock = Clock()
    door = WebDoor(str(VALVE), "cispi_valve", users_path, None, clock=clock)
    server = await started(door)
    base = str(server.make_url("/"))
    try:
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as web:
            async with web.get(base, allow_redirects=False) as r:
                assert r.status == 303 and r.headers["Location"] == "/signin"
            async with web.get(base + "signin") as r:
                page = await r.text()
                assert "Authorised staff only" in page and "cispi_valve" in page
                assert r.headers["X-Frame-Options"] == "DENY"
            async with web.get(base + "ws") as r:
                assert r.status == 403  # no session: no screen
            async with web.post(base + "signin", data={"name": "alice", "password": "nope"},
                                allow_redirects=False) as r:
                assert r.status == 401 and "wrong user name or password" in await r.text()
                assert COOKIE not in r.cookies
            async with web.post(base + "signin", data={"name": "alice",
                                                       "password": "alice-password"},
                                allow_redirects=False) as r:
                assert r.status == 303
                cookie = r.cookies[COOKIE]
                assert cookie["httponly"] and cookie["samesite"] == "Strict"
                assert not cookie["secure"]  # plain HTTP here (--cert/--key: Secure)
            async with web.get(base) as r:
                page = await r.text()
                assert "signed in as alice (operator)" in page
                assert f"ws://{server.host}:{server.port}/ws" in page
            async with web.get(base + "ws", headers={"Origin": "http://evil.example"}) as r:
                assert r.status == 403  # a page elsewhere cannot open our screens
            assert [s.user for s in door.table.list()] == ["alice"]
            async with web.post(base + "signout", allow_redirects=False) as r:
                assert r.status == 303 and r.headers["Location"] == "/signin"
            async with web.get(base, allow_redirects=False) as r:
                assert r.status == 303
            assert door.table.list() == []
    finally:
        await server.close()


async def test_an_idle_session_ends(users_path):
    clock = Clock()
    door = WebDoor(str(VALVE), "cispi_valve", users_path, None, clock=clock)
    server = await started(door)
    base = str(server.make_url("/"))
    try:
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as web:
            async with web.post(base + "signin", data={"name": "alice",
                                                       "password": "alice-password"}) as r:
                assert "signed in as alice" in await r.text()
            clock.now += 4 * 60
            async with web.get(base, allow_redirects=False) as r:
                assert r.status == 200
            clock.now += 61  # five minutes untouched (idle-lock = 5m)
            async with web.get(base, allow_redirects=False) as r:
                assert r.status == 303 and r.headers["Location"] == "/signin"
    finally:
        await server.close()


async def test_refused_sign_ins_and_the_lockout_go_to_the_journal(users_path, tmp_path):
    from hmi.explain.chain import verify
    from hmi.explain.journal import read
    journal = tmp_path / "journal.jsonl"
    door = WebDoor(str(VALVE), "cispi_valve", users_path, None, clock=Clock(),
                   journal=journal)
    server = await started(door)
    base = str(server.make_url("/"))
    tries = [("mallory", "whatever-it-is")] + [("alice", "guessing-wrong")] * 5 + [
        ("alice", "alice-password"), ("\x1b[2Jeve", "x")]
    try:
        async with aiohttp.ClientSession() as web:
            for name, password in tries:
                async with web.post(base + "signin", data={"name": name,
                                                           "password": password},
                                    allow_redirects=False) as r:
                    assert r.status == 401
    finally:
        await server.close()
    entries = [e for e in read(journal).entries
               if e["event"] in ("sign-in-refused", "account-locked")]
    assert [(e["event"], e["user"]) for e in entries] == (
        [("sign-in-refused", "mallory")] + [("sign-in-refused", "alice")] * 4
        + [("account-locked", "alice"), ("sign-in-refused", "alice"),
           ("sign-in-refused", "?[2Jeve")])
    assert all(e["door"] == "browser" and e["source"] == "127.0.0.1" and e["wall"]
               for e in entries)
    assert "locked for" in entries[5]["message"] and "locked" in entries[6]["message"]
    text = journal.read_text()
    assert "guessing-wrong" not in text and "alice-password" not in text
    assert verify(journal).intact  # linked like every other entry


def test_plchmi_web_refuses_what_cannot_be_served(capsys, tmp_path):
    assert main(["web", str(VALVE)]) == 2  # no users file: nobody could sign in
    assert "no users file" in capsys.readouterr().err
    users.add(Path(os.environ["PLCHMI_DATA"]) / "users", "alice", "operator", "alice-pw-1")
    assert main(["web", str(VALVE), "--cert", str(tmp_path / "c.pem")]) == 2
    assert "--cert and --key go together" in capsys.readouterr().err
    assert main(["web", str(VALVE), "--bind", "nowhere"]) == 2
    assert "expected HOST:PORT" in capsys.readouterr().err
    (tmp_path / "c.pem").write_text("not a certificate")
    (tmp_path / "k.pem").write_text("not a key")
    assert main(["web", str(VALVE), "--cert", str(tmp_path / "c.pem"), "--key",
                 str(tmp_path / "k.pem")]) == 2
    assert "not a certificate and its key" in capsys.readouterr().err
    assert main(["web", str(VALVE), "--bind", "127.0.0.1:0"]) == 1  # no runtime runs
    assert "no runtime runs cispi_valve" in capsys.readouterr().err


def test_https_with_a_certificate(tmp_path, users_path):
    """--cert/--key: the sign-in page over TLS, its cookie Secure."""
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    made = subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes",
                           "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj",
                           "/CN=localhost"], capture_output=True)
    if made.returncode != 0:
        pytest.skip(f"openssl could not make a test certificate: {made.stderr[-200:]!r}")
    from hmi.web.server import tls_context
    context = tls_context(cert, key)
    import asyncio
    import ssl

    async def run() -> None:
        door = WebDoor(str(VALVE), "cispi_valve", users_path, None, tls=True)
        server = TestServer(door.app(), host="127.0.0.1", port=0, ssl=context,
                            scheme="https")
        await server.start_server(ssl=context)
        trust = ssl.create_default_context(cafile=str(cert))
        trust.check_hostname = False
        try:
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as web:
                url = f"https://127.0.0.1:{server.port}/"
                async with web.post(url + "signin", ssl=trust, allow_redirects=False,
                                    data={"name": "alice", "password": "alice-password"}
                                    ) as r:
                    assert r.status == 303 and r.cookies[COOKIE]["secure"]
                with pytest.raises(aiohttp.ClientError):
                    async with web.get(f"http://127.0.0.1:{server.port}/signin") as r:
                        await r.text()  # plain HTTP is not served on the TLS port
        finally:
            await server.close()
    asyncio.run(run())
