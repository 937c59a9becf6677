"""The UI's pure parts, without an app: chronogram drawing, the recorder, the status line,
the reset preview, verdicts on manual requests, the fault dialog's delay."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rich.text import Text

from hmi.engine.snapshot import LatchReason
from hmi.explain.reset import PREVIEWS, ResetLine, reset_preview
from hmi.plant.base import PlantStatus
from hmi.session.recorder import ScanRecorder, Trace
from hmi.session.view import CellView
from hmi.ui.chronogram import FALL, HIGH, LOW, MULTI, RISE, UNKNOWN, axis, columns
from hmi.ui.fault_dialog import parse_delay
from hmi.ui.frame import Frame
from hmi.ui.status import Field, banner_lines, fit, join, late_help, status_fields
from hmi.ui.style import MUTED
from hmi.ui.verdict import output_changes, request_verdict
from tests.conftest import PROJECTS, make_session


def test_columns_draw_levels_edges_and_short_pulses():
    # 10 columns of 100 ms over (0, 1 s]: low, a rise at 250 ms, a fall at 550 ms,
    # a 20 ms pulse at 810-830 ms.
    trace = Trace(0, False, ((250_000, True), (550_000, False), (810_000, True),
                             (830_000, False)))
    drawn = columns(trace, 0, 1_000_000, 10)
    assert drawn == LOW * 2 + RISE + HIGH * 2 + FALL + LOW * 2 + MULTI + LOW


def test_columns_blank_before_the_first_sample_and_after_the_last_scan():
    trace = Trace(300_000, None, ((300_000, True),))
    drawn = columns(trace, 0, 1_000_000, 10, end_us=600_000)
    assert drawn == UNKNOWN * 2 + HIGH * 4 + UNKNOWN * 4


def test_axis_labels_round_times_on_their_column():
    row = axis(10_000_000, 10_000_000, 80)
    assert len(row) == 80
    assert "┊11s" in row and "┊19s" in row  # 20s would not fit at the right edge
    assert row.index("┊12s") == 2 * 80 // 10 - 1


def test_recorder_keeps_every_edge_even_between_frames():
    session = make_session(PROJECTS / "cispi_valve", inject=["F7@3s"])
    recorder = ScanRecorder(session.engine.layout)
    session.scan_listeners.append(recorder.on_scan)
    session.run_for(10_000_000)
    # F7: fsc reads 1 for 300 ms while the valve is away from closed: two edges, recorded
    trace = recorder.trace("fsc", 0, 10_000_000)
    times = [t for t, v in trace.changes]
    glitch = [(t, v) for t, v in trace.changes if 3_000_000 <= t <= 3_400_000]
    assert [v for _, v in glitch] == [True, False]
    assert glitch[1][0] - glitch[0][0] == 300_000
    assert times == sorted(times)
    assert recorder.scans == session.engine.scan
    o_fov = recorder.trace("O.fov", 0, 10_000_000)
    assert o_fov.changes == recorder.trace("O", 0, 10_000_000).changes  # no filter yet


def test_recorder_trace_initial_value_and_window():
    session = make_session(PROJECTS / "cispi_valve")
    recorder = ScanRecorder(session.engine.layout)
    session.scan_listeners.append(recorder.on_scan)
    session.run_for(6_000_000)
    trace = recorder.trace("fso", 4_000_000, 6_000_000)
    assert trace.initial is True  # open at 4 s
    assert all(4_000_000 < t <= 6_000_000 for t, _ in trace.changes)


def _frame(snap, **kw) -> Frame:
    return Frame(cell=CellView(snap), run=kw.pop("run", "running"), speed=1.0, live=False,
                 project="cispi_valve", **kw)


def _snapshot(**changes):
    session = make_session(PROJECTS / "cispi_valve")
    session.run_for(1_500_000)
    return session.last.snapshot._replace(**changes)


def test_status_keeps_alarms_and_mode_when_narrow():
    snap = _snapshot(latched=(LatchReason("plant", "connection lost", 3, 30_000),),
                     plant=PlantStatus("modbus", "modbus 127.0.0.1:5020", connected=False))
    fields = status_fields(_frame(snap, run="paused"), wide=False, compact=True)
    line = fit(fields, 40).plain
    assert "DISCONNECTED" in line and "SAFE STATE" in line and "AUTO" in line
    assert "PAUSED" in line
    assert "cispi_valve" not in line  # 40 columns: only the essentials are left
    full = fit(status_fields(_frame(snap), wide=True), 200).plain
    assert "cispi_valve" in full and "scan " in full


def test_status_at_80_columns_keeps_the_project_and_the_late_flag_over_scan_time():
    snap = _snapshot(scan_wall_us=1234.0)
    frame = _frame(snap, show_measured=True, overruns=3)
    full = fit(status_fields(frame, wide=True), 200).plain
    assert "1234 µs/scan" in full and "▲ 3 scans late" in full
    line = fit(status_fields(frame, wide=False, compact=True), 80).plain
    assert len(line) <= 80
    assert line.startswith(" cispi_valve │ ◇ SIM │ AUTO")  # the project is kept
    assert "µs" not in line  # this goes first
    assert "▲ 3 late" in line  # a compact late flag stays at every width
    for width in (60, 70):
        assert "▲ 3 late" in fit(status_fields(frame, wide=False, compact=True), width).plain
    assert "1 scan late" in fit(status_fields(_frame(snap, show_measured=True, overruns=1),
                                              wide=True), 200).plain
    assert "more than a whole scan period behind" in late_help(3)


def _cropped(line: str, width: int) -> str:
    """The status bar as drawn: a line too wide ends in "…" at its last cell."""
    return line if len(line) <= width else line[:width - 1] + "…"


@given(st.lists(st.tuples(st.integers(1, 24), st.integers(0, 3), st.integers(0, 2)),
                max_size=9), st.integers(0, 9), st.integers(24, 130))
def test_the_status_bar_keeps_the_alarm_count_whole(specs, at, width):
    """Whatever the other fields: the count of the most urgent alarms is whole on screen
    whenever it fits after the fields that never give way before it (before, the crop cut
    it to `✗ 1 P1 un…` when the fields kept longest were too wide), and those fields are
    all in the line (those after the count go, last first, when it needs their room)."""
    fields = [Field(Text(f"f{i}" + "x" * n), priority, gives_way=yields if not priority else 0)
              for i, (n, priority, yields) in enumerate(specs)]
    count = Field(Text("✗ 3 P1 unack"), 0, alarm_count=True)
    fields.insert(min(at, len(fields)), count)
    line = fit(fields, width).plain
    place = next(i for i, f in enumerate(fields) if f is count)
    never = [f for f in fields if f.priority == 0 and not f.gives_way]
    before = never[:next(i for i, f in enumerate(never) if f is count)]
    assert all(f.text.plain in line for f in [*before, count])
    if join([*before, count]).cell_len <= width - 1 or \
            join(fields[:place + 1]).cell_len <= width:
        assert "✗ 3 P1 unack" in _cropped(line, width), (line, width)
    if join(fields).cell_len <= width:  # room for all: nothing dropped
        assert line == join(fields).plain


def test_every_coloured_status_field_carries_a_symbol_or_word():
    snap = _snapshot(mode="manual", policy="monitor",
                     latched=(LatchReason("internal", "boom", 1, 0),))
    coloured = 0
    for field in status_fields(_frame(snap, run="stepping"), wide=True):
        styles = [span.style for span in field.text.spans] + [field.text.style]
        styles = [s for s in styles if s != MUTED]  # grey is the normal, quiet colour
        if any(getattr(s, "color", None) is not None or getattr(s, "bgcolor", None) is not None
               for s in styles):
            coloured += 1
            assert any(sym in field.text.plain for sym in ("▲", "✗")), field
    assert coloured == 4  # manual, monitor, safe state, stepping


def test_banner_lines_for_manual_and_latch():
    snap = _snapshot(mode="manual", manual=(("O", True),),
                     latched=(LatchReason("filter", "CSc1 violated", 5, 50_000),))
    lines = [line.plain for line in banner_lines(_frame(snap))]
    assert "MANUAL / FORCES ACTIVE" in lines[0] and "O=1" in lines[0]
    assert "OUTPUTS HELD IN SAFE STATE" in lines[1] and "a safety rule was broken" in lines[1]
    assert "CSc1" not in lines[1]  # the model's name: the engineering view's
    assert "CSc1 violated" in banner_lines(_frame(snap, engineering=True))[1].plain
    assert banner_lines(_frame(_snapshot())) == []
    lost = _snapshot(plant=PlantStatus("modbus", "modbus 127.0.0.1:5020", connected=False,
                                       message="connection refused"))
    line = banner_lines(_frame(lost))[0].plain
    assert "PLANT DISCONNECTED" in line and "connection refused" in line


def test_reset_preview_says_what_stays_and_why():
    snap = _snapshot(latched=(LatchReason("plant", "connection lost", 3, 30_000),
                              LatchReason("internal", "error at scan 4", 4, 40_000)),
                     plant=PlantStatus("modbus", "m", connected=False, message="timeout"))
    lines = reset_preview(snap)
    assert [line.resets for line in lines] == [True, False]  # resets first
    assert lines[0].what == "outputs held safe: internal error"
    assert "error at scan 4" in lines[0].detail  # the engineering view's
    assert "still disconnected" in lines[1].why and "timeout" in lines[1].why


def test_reset_preview_is_extensible():
    def alarms(snap):
        yield ResetLine("alarm A1 (acknowledged)", resets=True)

    PREVIEWS.append(alarms)
    try:
        assert [line.what for line in reset_preview(_snapshot())] == ["alarm A1 (acknowledged)"]
    finally:
        PREVIEWS.remove(alarms)


def test_output_changes_and_request_verdict_name_the_latch():
    snap = _snapshot()
    assert output_changes(snap) == {}
    latched = snap._replace(
        fov=(False, True), outputs=(False, False),
        latched=(LatchReason("internal", "boom", 1, 0),))
    assert output_changes(latched) == {"O": "held safe: boom"}
    ok, line = request_verdict(latched, "O", True)
    assert not ok and "written 0" in line and "held safe: boom" in line
    ok, line = request_verdict(latched, "C", False)
    assert ok and "written 0" in line


def test_request_verdict_names_a_device_the_operator_stopped():
    """A stopped device's outputs are held safe before the filter (the FOV is already safe):
    no change of the filter says why the request was not written, the device does."""
    snap = _snapshot()._replace(fov=(False, False), outputs=(False, False),
                                stopped_devices=("Valve V1",))
    ok, line = request_verdict(snap, "O", True, "Valve V1")
    assert not ok and "written 0" in line and "Valve V1 stopped by the operator" in line
    ok, line = request_verdict(snap._replace(stopped_devices=()), "O", True, "Valve V1")
    assert not ok and "changed by the output stage" in line


@pytest.mark.parametrize("text, us", [("", 0), ("now", 0), ("0", 0), ("5", 5_000_000),
                                      ("2.5", 2_500_000), ("500ms", 500_000),
                                      ("1.5s", 1_500_000)])
def test_parse_delay(text, us):
    assert parse_delay(text) == us


def test_parse_delay_rejects_words():
    with pytest.raises(ValueError):
        parse_delay("soon")


def test_recorder_counts_violation_episodes_from_every_scan():
    session = make_session(PROJECTS / "cispi_valve", control="faulty")
    recorder = ScanRecorder(session.engine.layout)
    violated_scans: dict[str, int] = {}

    def count(cell):
        for name in cell.snapshot.filter_report.violated_names:
            violated_scans[name] = violated_scans.get(name, 0) + 1

    session.scan_listeners.extend([recorder.on_scan, count])
    session.run_for(20_000_000)
    stats = recorder.constraint_stats()
    assert violated_scans and set(stats) == set(violated_scans)
    for name, scans in violated_scans.items():
        assert stats[name].scans == scans
        assert 1 <= stats[name].episodes <= scans
        assert stats[name].last_us is not None


def _columns_reference(trace, start, window, width, end):
    """Column by column, the plain definition the fast drawing must agree with."""
    out, value, k, changes = [], trace.initial, 0, trace.changes
    for c in range(width):
        lo = start + c * window // width
        hi = start + (c + 1) * window // width
        if end is not None and lo >= end:
            out.append(UNKNOWN)
            continue
        before, n = value, 0
        while k < len(changes) and changes[k][0] <= hi:
            value, n, k = changes[k][1], n + 1, k + 1
        if n == 0:
            out.append(UNKNOWN if value is None else (HIGH if value else LOW))
        elif n == 1:
            out.append((HIGH if value else LOW) if before is None else (RISE if value else FALL))
        else:
            out.append(MULTI)
    return "".join(out)


@given(st.lists(st.integers(1, 2_000_000), max_size=40, unique=True),
       st.sampled_from([None, False, True]), st.integers(1, 150),
       st.integers(1, 3_000_000), st.integers(0, 3_000_000))
def test_columns_agree_with_the_plain_definition(times, initial, width, window, end):
    value = initial if initial is not None else False
    changes = []
    for t in sorted(times):
        value = not value
        changes.append((t, value))
    changes = [(t, v) for t, v in changes if t <= end]
    trace = Trace(changes[0][0] if changes else None, initial, tuple(changes))
    assert columns(trace, 0, window, width, end) == \
        _columns_reference(trace, 0, window, width, end)


def test_recorder_forgets_old_history_but_keeps_the_level():
    session = make_session(PROJECTS / "cispi_valve")
    recorder = ScanRecorder(session.engine.layout, keep_us=10_000_000)
    session.scan_listeners.append(recorder.on_scan)
    session.run_for(60_000_000)
    kept = recorder._changes[recorder.by_name["O"]]
    assert kept[0][0] <= 60_000_000 - 10_000_000  # the level before the kept window...
    assert len(kept) <= 6  # ...and about 12.5 s of an 8 s cycle, not 60 s of it
    full = ScanRecorder(session.engine.layout)  # a fresh run, never trimmed, agrees
    again = make_session(PROJECTS / "cispi_valve")
    again.scan_listeners.append(full.on_scan)
    again.run_for(60_000_000)
    window = (50_000_000, 60_000_000)
    assert recorder.trace("O", *window).changes == full.trace("O", *window).changes
    assert recorder.trace("O", *window).initial == full.trace("O", *window).initial


def test_the_message_line_names_an_alarm_by_its_text_and_never_twice():
    from hmi.engine.commands import (
        Acknowledge,
        ChoosePolicy,
        CommandResult,
        SetMode,
        Shelve,
        StartRecovery,
        Unshelve,
    )
    from hmi.ui.message_line import result_text, spoken

    key, text = "constraint:CSs2", "Valve V1: open order blocked"
    texts = {key: text}.get

    def line(command, result):
        said, answer = spoken(command, result, lambda k: texts(k, k))
        return result_text(said, result, answer).plain

    assert line(Acknowledge(key), CommandResult.ok("acknowledged 1 alarm")) == \
        f"✓ acknowledged 1 alarm: {text}"
    refused = line(Acknowledge(key), CommandResult.refused(f"already acknowledged: {text}"))
    assert refused.count(text) == 1 and key not in refused
    gone = line(Acknowledge("diagnoser:V9"), CommandResult.refused(
        "no alarm diagnoser:V9 to acknowledge"))  # nothing names it any more: its key
    assert "diagnoser:V9" in gone
    shelved = line(Shelve(key, 600_000_000), CommandResult.ok(
        f"{text}: shelved for 10 min; journalled meanwhile"))
    assert shelved.count(text) == 1 and key not in shelved and "shelve alarm" in shelved
    back = line(Unshelve(key), CommandResult.refused(f"alarm {key} is not shelved"))
    assert f"“{text}”" in back and key not in back
    chosen = line(ChoosePolicy(key, "continue"), CommandResult.ok(
        f"policy 'Continue' chosen for {key}: let the filter keep correcting"))
    assert chosen == "✓ policy 'Continue' chosen: let the filter keep correcting"
    recovery = line(StartRecovery("V1_close"), CommandResult.ok(
        "RECOVERY mode: Close valve V1 (its initial position)"))
    assert "V1_close" not in recovery and recovery.startswith("✓ start recovery: RECOVERY")
    manual = line(SetMode(True), CommandResult.ok(
        "manual mode: the control program waits at X3; outputs follow operator requests"))
    assert manual == "✓ manual mode: the control program waits at X3; outputs follow " \
        "operator requests"
    auto = line(SetMode(False), CommandResult.ok("automatic mode: the control program "
                                                 "resumes from X3"))
    assert auto == "✓ automatic mode: the control program resumes from X3"
    assert line(SetMode(True), CommandResult.refused("already in manual mode")) == \
        "✗ REFUSED enter manual mode: already in manual mode"


def test_manual_dialog_lines_name_the_steps_and_the_orders_given_again(tmp_path):
    """hmi.ui.manual: a GRAFCET's steps with their descriptions (a step without one by its
    name), the outputs the steps' continuous actions order again; a law of equations only
    says its memories hold."""
    from hmi.ui import manual
    from tests.conftest import write_project
    session = make_session(PROJECTS / "conveyor_robot")
    project = session.engine.project
    law = project.controls[session.engine.control_name]
    snap = session.scan_once().snapshot
    assert snap.active_steps == ("X1", "X11")
    assert manual.ordered_again(project, law, snap.active_steps) == ("d", "G")
    assert manual.steps_text(law, ("X3", "X10")) == (
        "X3 (A pallet waits at B), X10 (Robot free at home)")
    assert manual.leave_lines(project, law, snap)[-1] == (
        "These steps order d, G again at the next scan.")
    assert manual.enter_lines(project, law, snap)[0].startswith(
        "The control program waits at the steps it is in when you confirm (when this "
        "opened, at 0.000 s: X1 (Pusher puts the next pallet on the conveyor), X11 ")
    folder = write_project(tmp_path / "eq", {"project.yaml": """
        name: eq
        scan_period: 10ms
        inputs: {a: A, fsc: sensor, fso: sensor}
        outputs: {C: order, O: order}
        memories: {M: {description: memory}}
        control:
          equations:
            M: {set: a, reset: fsc}
            C: M
        plant: {kind: sim, model: valve, ports: {C: C, O: O}}
    """})
    session = make_session(folder)
    project = session.engine.project
    law = project.controls[session.engine.control_name]
    snap = session.scan_once().snapshot
    assert manual.enter_lines(project, law, snap) == [
        "The control program waits: its equations are not evaluated and its memories hold "
        "until you leave manual mode; it then resumes from there."]
    assert manual.ordered_again(project, law, ()) == ()
    assert "memories as they were" in manual.leave_lines(project, law, snap)[0]


def test_the_journal_words_of_a_reset_line_are_the_dialogs():
    """What the runtime journals of a declined reset (hmi.explain.reset.line_text) reads as
    the dialog showed it (hmi.ui.reset.reset_line)."""
    from hmi.explain.reset import line_text
    from hmi.ui.reset import reset_line
    for line in (ResetLine("monitor label F", resets=True),
                 ResetLine("diagnoser V1", resets=True, note="re-synchronised to N1"),
                 ResetLine("latch", resets=False, why="its cause is still present"),
                 ResetLine("V1 stopped", resets=False, note="release it from the palette"),
                 ResetLine("recovery running", resets=False)):
        assert line_text(line) == reset_line(line).plain
