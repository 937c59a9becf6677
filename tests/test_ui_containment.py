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
from tests.runtimes import wait_for
from tests.test_modbus import server  # noqa: F401  (the fixture: real server processes)

SIZE = (100, 30)


def journal_entries(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def journalled(app: PlcHmiApp, path: Path) -> JournalRecorder:
    """The journal listening to the app's session and to its UI errors, as cmd_ui does."""
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


def cell_runs(project_name: str = "cispi_valve"):
    """The pid of the project's runtime, if one runs (its lock is held)."""
    from hmi.runtime.place import place, running
    return running(place(project_name))


def test_an_app_crash_exits_non_zero_the_runtime_journals_it_and_runs_on(monkeypatch,
                                                                         tmp_path, capsys):
    """A screen that crashes is the screen's end, not the cell's: its error is journalled by
    the runtime (with who), the screen exits 1, and the cell runs on."""
    path = tmp_path / "j.jsonl"
    inject(monkeypatch, "fatal@0.5s")
    status = run_hmi_headless(monkeypatch, [str(VALVE), "--journal", str(path)])
    assert status == 1
    err = capsys.readouterr().err
    assert "the HMI ended on an error" in err and "deliberate error outside any handler" in err
    assert "the cell runs on" in err
    assert cell_runs() is not None
    # (the runtime journals in the background: its entry of the screen leaving comes soon)
    entries = wait_for(lambda: (found := journal_entries(path)) and any(
        e["event"] == "client-left" for e in found) and found, "the screen's leaving")
    fatal = [e for e in entries if e["event"] == "ui-error"]
    assert len(fatal) == 1 and fatal[0]["fatal"] is True and fatal[0]["by"].startswith(
        "terminal:")
    assert Path(fatal[0]["crash_file"]).is_file()
    assert "the cell runs on" in fatal[0]["message"]
    assert not any(e["event"] in ("abnormal-end", "stop") for e in entries)


def test_an_app_crash_on_a_real_plant_leaves_the_cell_controlled(monkeypatch, tmp_path,
                                                                 server):  # noqa: F811
    """The screen crashes while the valve opens: the runtime goes on driving the plant (its
    scans continue against the device); stopped, it leaves the outputs safe."""
    from hmi.link.base import Identity
    from hmi.link.client import SocketLink
    from hmi.project.kept import fingerprint, load_once
    from hmi.runtime.place import place
    srv = server(VALVE)
    path = tmp_path / "j.jsonl"
    # the valve's program opens it after 1 s: the crash comes while O is driven
    inject(monkeypatch, "fatal@1.5s")
    status = run_hmi_headless(monkeypatch, [str(VALVE), "--plant",
                                            f"modbus://127.0.0.1:{srv.port}",
                                            "--journal", str(path)])
    assert status == 1
    project = load_once(VALVE)
    link = SocketLink(project, place(project.name).socket, fingerprint(VALVE, None),
                      Identity("after", "operator"))
    assert link.first_frame.wait(60)
    scan = link.last.snapshot.scan
    wait_for(lambda: link.last.snapshot.scan > scan + 10, "the runtime scanning on")
    assert link.last.snapshot.plant.connected
    link.leave(stop_cell=True)
    wait_for(lambda: cell_runs() is None, "the runtime to stop")
    entries = journal_entries(path)
    assert entries[-1]["event"] == "stop"
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


def test_a_dead_scan_thread_ends_the_runtime_abnormally(monkeypatch, tmp_path, capsys):
    """The runtime's scan thread dying ends the runtime as an abnormal end (exit 1, the
    journal says why): nothing scans any more (plchmi serve, here in this process)."""
    path = tmp_path / "j.jsonl"
    on_scan = JournalRecorder.on_scan

    def failing(self, cell):
        if cell.snapshot.scan == 30:
            raise OSError(28, "No space left on device")
        on_scan(self, cell)
    monkeypatch.setattr(JournalRecorder, "on_scan", failing)
    assert main(["serve", str(VALVE), "--journal", str(path), "--no-realtime"]) == 1
    assert "the scan thread stopped: OSError" in capsys.readouterr().err
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
