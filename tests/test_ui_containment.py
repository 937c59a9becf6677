"""Fault containment: a UI error never stops the scan and never ends the HMI
silently; an error the app cannot carry on after ends it as an abnormal end.

The deliberate errors come from tests/ui_faults.py (wrapped around the app's frame refresh)
or from a handler replaced by one that raises.
"""

from __future__ import annotations

import json
from functools import partialmethod
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient
from textual.app import App
from ui_faults import inject, parse
from ui_harness import palette, region_text, run_for, wait_for_main
from ui_scenarios import VALVE, make_app

from hmi.cli import main
from hmi.explain.journal import Journal
from hmi.session.journal_recorder import JournalRecorder
from hmi.ui.app import PlcHmiApp, app_end
from hmi.ui.chronogram import Chronogram
from hmi.ui.constraints_panel import ConstraintsPanel
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.headless import click, press, settle, wait_for_screen
from tests.test_modbus import server  # noqa: F401  (the fixture: real server processes)

SIZE = (100, 30)


def journal_entries(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def journalled(app: PlcHmiApp, path: Path) -> JournalRecorder:
    """The journal listening to the app's controller and to its UI errors, as cmd_ui does."""
    recorder = JournalRecorder(app.link.session, Journal(path), "test")
    app.containment.listeners.append(recorder.on_ui_fault)
    return recorder


async def test_a_panel_raising_at_every_frame_is_contained(monkeypatch, tmp_path):
    inject(monkeypatch, "panel@2s")
    app = make_app(control="faulty")
    recorder = journalled(app, tmp_path / "j.jsonl")
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 1.0)
        assert app.containment.latest is None
        assert region_text(app, "#constraints").strip("│╭╮╰╯─ \n")  # drawn before 2 s
        await run_for(pilot, 2.0)
        fault = app.containment.latest
        assert fault is not None and fault.what == "ConstraintsPanel refresh"
        assert "deliberate error in the constraints panel" in fault.error
        banner = region_text(app, "#banners")
        assert "UI ERROR" in banner and "ConstraintsPanel" in banner
        report = Path(fault.report)
        assert report.is_file() and "DeliberateUIError" in report.read_text()
        # the scan and every other panel go on
        for seconds in (3, 4):
            before = app.frames_shown
            await run_for(pilot, 1.0)
            assert app.frames_shown > before
            assert app.link.session.engine.now >= seconds * 1_000_000
            assert f"scan {app.link.session.engine.scan}" in region_text(app, "#status")
        # counted, not written again: one crash file, one journal entry
        assert app.containment.faults[("ConstraintsPanel refresh",
                                       "DeliberateUIError")].count > 2
        assert len(list(report.parent.glob("crash-*.txt"))) == 1
        assert app.is_running and app.return_code is None
    end = app_end(app)
    assert end.status == 0 and end.reason is None  # the operator ended it
    recorder.close(end.reason, end.note)
    entries = journal_entries(tmp_path / "j.jsonl")
    errors = [e for e in entries if e["event"] == "ui-error"]
    assert len(errors) == 1 and errors[0]["what"] == "ConstraintsPanel refresh"
    assert errors[0]["fatal"] is False and errors[0]["crash_file"] == str(report)
    # contained: the operator ended it, but never "normally" after errors
    assert entries[-1]["event"] == "stop"
    assert "ended as asked, after" in entries[-1]["message"]
    assert "contained UI errors (first: ConstraintsPanel refresh" in entries[-1]["message"]
    assert "normally" not in entries[-1]["message"]


async def test_errors_in_handlers_actions_dialogs_palette_and_drawing_are_contained(
        monkeypatch):
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 1.0)

        def boom(*args, **kwargs):
            raise ValueError("deliberate")

        # a key's action
        monkeypatch.setattr(PlcHmiApp, "action_window", boom)
        await press(pilot, "w")
        await settle(pilot)
        assert app.containment.latest.what == "action window"
        # a click handler of a panel
        monkeypatch.setattr(ConstraintsPanel, "on_click", boom)
        assert await click(pilot, "#constraints")
        await settle(pilot)
        assert app.containment.latest.what == "ConstraintsPanel on_click"
        # the answer to a dialog
        monkeypatch.setattr(PlcHmiApp, "_reset_if_unchanged", boom)
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert app.containment.latest.what.startswith("answer to reset-dialog")
        # a palette entry
        monkeypatch.setattr(PlcHmiApp, "action_step", boom)
        await palette(pilot, "Step one scan")
        await settle(pilot)
        assert "Step one scan" in app.containment.latest.what
        # drawing (Textual's compositor calls render outside any handler; headless in
        # virtual time, the screen is drawn when looked at: hmi.ui.driver)
        monkeypatch.setattr(Chronogram, "_draw_text", boom)
        app.chronogram.refresh()
        await run_for(pilot, 0.5)
        assert "chronogram not drawn" in region_text(app, "#chronogram")
        assert app.containment.latest.what == "Chronogram drawing"
        # and through it all the scan ran and the app lived
        scan = app.link.session.engine.scan
        await run_for(pilot, 1.0)
        assert app.link.session.engine.scan > scan
        assert app.is_running and app.containment.fatal is None
        assert "UI ERROR" in region_text(app, "#banners")


def run_hmi_headless(monkeypatch, argv: list[str]) -> int:
    """`plchmi ARGS` in this process, the Textual app headless (no terminal in a test)."""
    monkeypatch.setattr(PlcHmiApp, "run", partialmethod(App.run, headless=True))
    return main(argv)


def test_an_app_crash_exits_non_zero_with_an_abnormal_end_journalled(monkeypatch, tmp_path,
                                                                     capsys):
    path = tmp_path / "j.jsonl"
    inject(monkeypatch, "fatal@0.5s")
    status = run_hmi_headless(monkeypatch, [str(VALVE), "--journal", str(path)])
    assert status == 1
    err = capsys.readouterr().err
    assert "the HMI ended on an error" in err and "deliberate error outside any handler" in err
    entries = journal_entries(path)
    fatal = [e for e in entries if e["event"] == "ui-error"]
    assert len(fatal) == 1 and fatal[0]["fatal"] is True
    assert Path(fatal[0]["crash_file"]).is_file()
    last = entries[-1]
    assert last["event"] == "abnormal-end" and "ended abnormally" in last["message"]
    assert "DeliberateUIError" in last["message"]
    assert not any("ended normally" in e.get("message", "") for e in entries)


def test_an_app_crash_on_a_real_plant_leaves_its_outputs_safe(monkeypatch, tmp_path,
                                                              server):  # noqa: F811
    srv = server(VALVE)
    path = tmp_path / "j.jsonl"
    # the valve's program opens it after 1 s: the crash comes while O is driven
    inject(monkeypatch, "fatal@1.5s")
    status = run_hmi_headless(monkeypatch, [str(VALVE), "--plant",
                                            f"modbus://127.0.0.1:{srv.port}",
                                            "--journal", str(path)])
    assert status == 1
    entries = journal_entries(path)
    assert entries[-1]["event"] == "abnormal-end"
    client = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=5)
    assert client.connect()
    try:
        coils = client.read_coils(0, count=2, device_id=1)
        assert not coils.isError()
        assert coils.bits[:2] == [False, False]  # C and O: the valve's safe vector
    finally:
        client.close()


def test_the_hook_says_what_it_expects(monkeypatch):
    with pytest.raises(ValueError, match="expected panel or fatal"):
        parse("everywhere")


def test_a_dead_scan_thread_ends_the_hmi_abnormally(monkeypatch, tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    on_scan = JournalRecorder.on_scan

    def failing(self, snapshot):
        if snapshot.scan == 30:
            raise OSError(28, "No space left on device")
        on_scan(self, snapshot)
    monkeypatch.setattr(JournalRecorder, "on_scan", failing)
    assert run_hmi_headless(monkeypatch, [str(VALVE), "--journal", str(path)]) == 1
    assert "the scan thread: OSError" in capsys.readouterr().err
    entries = journal_entries(path)
    assert entries[-1]["event"] == "abnormal-end"
    assert "the scan thread" in entries[-1]["message"]


def test_a_headless_run_that_fails_is_not_journalled_as_ended_normally(monkeypatch,
                                                                        tmp_path):
    from hmi.session.session import Session
    path = tmp_path / "j.jsonl"

    def broken(self, duration_us, *args, **kwargs):  # whatever run_for is given
        raise RuntimeError("deliberate")
    monkeypatch.setattr(Session, "run_for", broken)
    assert main(["run", str(VALVE), "--for", "1s", "--journal", str(path)]) == 1
    last = journal_entries(path)[-1]
    assert last["event"] == "abnormal-end"
    assert last["message"].endswith("internal error: RuntimeError: deliberate")
