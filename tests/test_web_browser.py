"""The HMI in a real browser: Debian's chromium driven by playwright against ``plchmi web``,
in front of a real runtime (``plchmi serve``, real time) and a real users file.

What the browser shows is read from what it was sent: every byte of each tab's websocket
goes through an independent terminal emulator (pyte), as xterm.js draws it into its canvas;
keys are pressed in the page, as a person would. The journal is the runtime's file.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import parse_qs, urlparse

import pytest

from hmi.access import users
from hmi.explain.journal import read
from tests.conftest import PROJECTS
from tests.runtimes import ROOT, RuntimeProcess, wait_for

pytestmark = pytest.mark.slow

VALVE = PROJECTS / "cispi_valve"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
PASSWORDS = {"alice": "alice-password", "bob": "bob-password", "carol": "carol-password"}
ROLES = {"alice": "operator", "bob": "viewer", "carol": "operator"}
GUARD_S = 120.0  # a hang guard only: every wait is on state


def _browser_or_why():
    if not Path(CHROMIUM).is_file():
        pytest.skip(f"no chromium at {CHROMIUM}: Debian's chromium is not installed "
                    "(apt-get install -y chromium; .ci/run installs it where it runs as root "
                    "with apt): the real-browser test cannot run here")
    try:
        import pyte  # noqa: F401
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        pytest.skip(f"{exc.name} is not installed (pip install -e '.[test]'): the "
                    "real-browser test cannot run here")
    return sync_playwright


class Tab:
    """One browser tab, its screen as the bytes it received draw it."""

    def __init__(self, browser, url: str):
        import pyte
        self.context = browser.new_context(viewport={"width": 1400, "height": 900})
        self.page = self.context.new_page()
        self.screen = pyte.Screen(200, 60)
        self.stream = pyte.ByteStream(self.screen)
        self.page.on("websocket", self._socket)
        self.url = url

    def _socket(self, socket) -> None:
        query = parse_qs(urlparse(socket.url).query)
        if "width" in query:
            self.screen.resize(int(query["height"][0]), int(query["width"][0]))
        socket.on("framereceived", self._received)

    def _received(self, payload) -> None:
        if isinstance(payload, bytes):  # the app's output (text frames are textual-serve's)
            self.stream.feed(payload)

    def text(self) -> str:
        return "\n".join(self.screen.display)

    def sign_in(self, name: str, password: str) -> str:
        """The sign-in page's answer: "" when signed in, else what it says."""
        self.page.goto(self.url + "signin")
        self.page.fill("#name", name)
        self.page.fill("#password", password)
        self.page.click("#sign-in")
        self.page.wait_for_load_state()
        if self.page.locator("#problem").count():
            return self.page.inner_text("#problem")
        return ""

    def wait_text(self, pattern: str, what: str) -> re.Match[str]:
        started = time.monotonic()
        while True:
            found = re.search(pattern, self.text())
            if found:
                return found
            if time.monotonic() - started > GUARD_S:
                raise AssertionError(f"{what}: not on the screen within {GUARD_S:g} s:\n"
                                     + self.text())
            self.page.wait_for_timeout(50)

    def wait_gone(self, pattern: str, what: str) -> None:
        started = time.monotonic()
        while re.search(pattern, self.text()):
            if time.monotonic() - started > GUARD_S:
                raise AssertionError(f"{what}: still on the screen after {GUARD_S:g} s:\n"
                                     + self.text())
            self.page.wait_for_timeout(50)

    def press(self, key: str) -> None:
        self.page.click("#terminal")
        self.page.keyboard.press(key)


@contextlib.contextmanager
def web_door(sock: Path, log: Path, journal: Path):
    command = [sys.executable, "-m", "hmi.cli", "web", str(VALVE), "--bind", "127.0.0.1:0",
               "--socket", str(sock), "--journal", str(journal)]
    with open(log, "wb") as out:
        process = subprocess.Popen(command, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=out,
                                   stderr=out)
    try:
        found = wait_for(lambda: process.poll() is not None or re.search(
            r"https?://127\.0\.0\.1:\d+/", log.read_text()), "the web door's address")
        assert process.poll() is None, log.read_text()
        yield found.group(0)
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
        process.wait(GUARD_S)


def acknowledgements(journal: Path) -> list[dict]:
    return [e for e in read(journal).entries
            if e.get("type") == "action" and "acknowledge" in e.get("event", "")]


def test_operator_viewer_and_lockout_in_a_real_browser(tmp_path):
    sync_playwright = _browser_or_why()
    data = Path(os.environ["PLCHMI_DATA"])
    for name, password in PASSWORDS.items():
        users.add(data / "users", name, ROLES[name], password)
    sock = tmp_path / "cell" / "runtime.sock"
    journal = tmp_path / "journal.jsonl"
    # real time: the valve cycles on its own; the fault comes once both have signed in
    cell = RuntimeProcess(VALVE, sock, "--journal", str(journal), "--inject", "F13@40s",
                          virtual=False)
    try:
        with web_door(sock, tmp_path / "web.log", journal) as url, sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            # the sixth wrong password: five wrong lock the account, then even the right one
            # is refused
            guess = Tab(browser, url)
            for attempt in range(1, 6):
                said = guess.sign_in("carol", f"wrong-{attempt}")
                assert "wrong user name or password" in said, said
            assert "locked" in said
            said = guess.sign_in("carol", PASSWORDS["carol"])
            assert "locked" in said and guess.page.url.endswith("/signin"), said
            guess.context.close()
            # an operator signs in and sees the valve cycle
            alice = Tab(browser, url)
            assert alice.sign_in("alice", PASSWORDS["alice"]) == ""
            assert alice.page.inner_text("#who").endswith("signed in as alice (operator)")
            seen = set()
            while len(seen) < 3:  # the GRAFCET's active step changes: the valve moves
                seen.add(alice.wait_text(r"│ ● (\S[^│]*?)\s{2,}", "the active step").group(1))
                alice.page.wait_for_timeout(100)
            alice.page.screenshot(path=str(tmp_path / "browser.png"))
            # a viewer sees the same cell, and cannot acknowledge
            bob = Tab(browser, url)
            assert bob.sign_in("bob", PASSWORDS["bob"]) == ""
            for tab in (bob, alice):
                tab.wait_text(r"Valve V1: sensor fso stuck", "the alarm")
            bob.press("A")
            refused = wait_for(lambda: acknowledgements(journal), "bob's acknowledgement")
            assert refused[0]["by"] == "browser:bob" and refused[0]["role"] == "viewer"
            assert refused[0].get("accepted") is False or "refused" in str(refused[0])
            bob.wait_text(r"viewer", "the refusal on bob's screen")
            # the operator acknowledges it: in the journal with her name
            alice.press("A")
            entries = wait_for(lambda: [e for e in acknowledgements(journal)
                                        if e["by"] == "browser:alice"], "alice's ack")
            assert entries[0]["role"] == "operator" and entries[0]["door"] == "browser"
            assert entries[0].get("accepted", True) is not False, entries[0]
            alice.wait_text(r"acknowledged", "the acknowledgement on alice's screen")
            browser.close()
    finally:
        cell.stop()
    entries = read(journal).entries
    refused = [(e["event"], e["by"], e["source"]) for e in entries
               if e["event"] in ("sign-in-refused", "account-locked")]
    assert refused == [("sign-in-refused", "browser:carol", "127.0.0.1")] * 4 + [
        ("account-locked", "browser:carol", "127.0.0.1"),
        ("sign-in-refused", "browser:carol", "127.0.0.1")], refused
    verified = subprocess.run([sys.executable, "-m", "hmi.cli", "journal", "verify",
                               str(VALVE), "--path", str(journal)], cwd=ROOT,
                              capture_output=True, text=True)
    assert verified.returncode == 0, verified.stdout + verified.stderr
