"""Pilot tests of the diagnosers on the operator screen: the panel, the I/O marks, the
diagnosis explanations (certain and ambiguous), their alarms and policies, and the reset.

The faults are injected in the simulated valve exactly as the fault dialog does
(InjectFault through the app), and the valve's diagnoser V1 decides (projects/cispi_valve/
diagnoser.yaml): F1 at 10 s ends in A1 {F1, F13} (ambiguous, orders masked: final in the paper
variant, used here); F9 at 10 s is isolated with certainty in S9 (fso read from its estimate).
"""

from __future__ import annotations

from ui_harness import region_text, run_until, screen_text, wait_for_main
from ui_scenarios import make_app

from hmi.engine.commands import InjectFault
from hmi.project.injection import Injection
from hmi.ui.alarm_list import AlarmList
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.explain_panel import ExplanationPanel
from hmi.ui.headless import press, settle, wait_for_screen, wait_until

WIDE = (120, 36)


def engine(app):
    return app.link.session.engine


def flat(app, selector: str) -> str:
    lines = [line.strip("│╭╮╰╯─ ") for line in region_text(app, selector).splitlines()]
    return " ".join(" ".join(lines).split())


def at_rest_open(cell) -> bool:
    """No order, and the valve reads open."""
    s = cell.snapshot
    return not s.output_map["C"] and not s.output_map["O"] and s.value("fso") \
        and not s.value("fsc")


def decided(labels: tuple[str, ...]):
    return lambda s: bool(s.snapshot.diagnosers) and s.snapshot.diagnosers[0].labels == labels


async def inject(pilot, code: str, at_s: float, labels: tuple[str, ...]) -> None:
    pilot.app.send(InjectFault(Injection(code, int(at_s * 1_000_000))))
    await run_until(pilot, decided(labels), 30, f"the diagnoser deciding {labels}")


async def test_normal_diagnoser_is_quiet():
    app = make_app()
    async with app.run_test(size=WIDE) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        await run_until(pilot, lambda s: s.snapshot.diagnosers
                        and s.snapshot.diagnosers[0].state == "N5", 10, "open at rest")
        text = region_text(app, "#diagnosers")
        assert "Diagnosers · 1" in text and "faulty" not in text
        assert "● V1 N5 Open at rest" in text
        assert "flags  def_fsc  def_fso  def_V" in text  # none set: no symbol, no colour
        assert "✗" not in text and "▲" not in text


async def test_ambiguous_diagnosis_reads_as_such():
    app = make_app(diagnoser="paper")
    async with app.run_test(size=WIDE) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        await inject(pilot, "F1", 10, ("F1", "F13"))
        snap = app.link.session.last
        assert set(snap.snapshot.masked) == {"C", "O"} and snap.snapshot.reconstructed == ("fsc",)
        text = region_text(app, "#diagnosers")
        assert "✗ V1 A1" in text and "1 faulty" in text
        assert "{F1, F13} ? ambiguous" in text
        assert "▲ def_fsc" in text and "✗ def_V" in text
        assert "≈ fsc from fsc_hat" in text and "⊘ C, O masked (def_V)" in text
        io = region_text(app, "#io")
        assert "≈ estimated closed position" in io  # the operator's words, not fsc_hat
        assert io.count("⊘ masked by the diagnosis") == 2 and "def_V" not in io
        # its alarm, selected first (P1), and the explanation that says "ambiguous"
        alarm = snap.alarms[0]
        assert alarm.key == "diagnosis:V1" and alarm.latched and alarm.priority == 1
        assert app.query_one(AlarmList).selected == "diagnosis:V1"
        assert "? ambiguous" in region_text(app, "#alarms")
        explained = flat(app, "#explain")
        assert "? AMBIGUOUS" in explained and "LATCHED" in explained
        assert "sensor fsc stuck at 0, or valve blocked between its positions — closed end " \
            "switch ignored, no longer driven" in explained
        assert "recommended: Check Valve V1 first" in explained
        await press(pilot, "e", "e", "e")
        await wait_until(pilot, lambda: app.focused is not None
                         and "policy-button" in app.focused.classes, "the policies")
        await settle(pilot)
        assert app.focused.policy.id == "check"  # recommended: check the valve first
        assert "★ Check Valve V1 first" in str(app.focused.label)
        panel = app.query_one(ExplanationPanel)
        panel.scroll_home(animate=False)
        await settle(pilot)
        assert "cannot tell them apart" in flat(app, "#explain")


async def test_certain_diagnosis_recommends_running_degraded():
    app = make_app()
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(cmd))
    async with app.run_test(size=WIDE) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        await inject(pilot, "F9", 10, ("F9",))
        snap = app.link.session.last
        assert snap.snapshot.reconstructed == ("fso",) and snap.snapshot.masked == ()
        assert "F9 ✗ certain  unexpected fso rise" in region_text(app, "#diagnosers")
        assert "≈ estimated open position" in region_text(app, "#io")
        explained = flat(app, "#explain")
        assert "unexpected fso rise (0 to 1) — open end switch ignored" in explained
        assert "AMBIGUOUS" not in explained
        app.explain("diagnosis:V1", open_level=4)
        await wait_until(pilot, lambda: app.focused is not None
                         and "policy-button" in app.focused.classes, "the policies")
        assert app.focused.policy.id == "continue"
        await press(pilot, "enter")  # nothing sent to the plant: no confirmation
        await settle(pilot)
        assert len(app.screen_stack) == 1
        assert seen[-1].policy == "continue"
        assert "✓ Continue degraded chosen: keep running on the reconstructed value" in \
            flat(app, "#explain")


async def test_reset_re_synchronises_a_diagnoser_only_when_the_io_allows_it():
    app = make_app()
    async with app.run_test(size=WIDE) as pilot:
        await inject(pilot, "F1", 10, ("F1", "F13"))
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "stays: Valve V1's diagnosis: sensor fsc stuck at 0 or valve blocked" in text
        said = " ".join(getattr(line, "plain", str(line)) for line in app.screen.lines)
        assert "reset needs Valve V1 back at a known position" in said
        assert "g: start recovery" in text  # the way back is offered (tests/test_recovery.py)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).diagnosis.runtimes[0].state.name == "A1"
        assert "stays: Valve V1's diagnosis" in app.message.plain
    app = make_app()
    async with app.run_test(size=WIDE) as pilot:
        await inject(pilot, "F9", 10, ("F9",))
        await run_until(pilot, at_rest_open, 10, "the valve at rest")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "will be reset: Valve V1's diagnosis: unexpected fso" in text
        said = " ".join(getattr(line, "plain", str(line)) for line in app.screen.lines)
        assert "its watch starts again from what the I/O show now: fsc=0, fso=1, C=0, O=0" \
            in said
        assert "N5" not in text and "S9" not in text  # the model's names: engineering view
        assert "1 latched alarm clears with its latch" in text
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).diagnosis.runtimes[0].state.name == "N5"
        await run_until(pilot, lambda s: not s.snapshot.diagnosers[0].faulty, 1, "the next scan")
        assert "faulty" not in region_text(app, "#diagnosers")
        assert "○ CLEARED-UNACK" in region_text(app, "#alarms")


async def test_diagnosers_panel_keeps_one_line_at_80x24():
    app = make_app(diagnoser="paper")  # A1 final: the longest decision text
    async with app.run_test(size=(80, 24)) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        await inject(pilot, "F1", 10, ("F1", "F13"))
        text = region_text(app, "#diagnosers")
        assert "✗ V1 A1 {F1, F13} ? ambiguous" in text
        assert "active" in region_text(app, "#control")  # the control lists active steps
        screen = app.screen.region
        for selector in ("#status", "#alarms", "#diagnosers", "HmiFooter"):
            assert screen.contains_region(app.query_one(selector).region), selector


async def test_a_situation_without_alarm_is_explained_from_the_palette():
    from ui_harness import palette

    app = make_app()
    async with app.run_test(size=WIDE) as pilot:
        await inject(pilot, "F9", 10, ("F9",))
        degraded = next(e for e in app.link.session.last.explanations
                        if e.key == "reconstruction:fso")
        assert not degraded.alarm  # the diagnosis raised the alarm; this one explains more
        await palette(pilot, f"Explain: {degraded.what}", "fso ignored")
        assert app.query_one(ExplanationPanel).key == "reconstruction:fso"
        assert app.query_one(AlarmList).selected == "diagnosis:V1"  # the list is unchanged
        explained = flat(app, "#explain")
        assert "severity" not in explained and "(no alarm)" in explained
        assert "▾ Why" in explained
        # enter on the alarm list brings the explanation back to the selected alarm
        app.query_one(AlarmList).focus()
        await press(pilot, "home")
        await settle(pilot)
        assert app.query_one(ExplanationPanel).key == "reconstruction:fso"  # no move: kept
        await press(pilot, "enter")
        await settle(pilot)
        assert app.query_one(ExplanationPanel).key == "diagnosis:V1"
        assert app.query_one(ExplanationPanel).level >= 2


async def test_at_80_columns_the_io_marks_take_their_short_form():
    """About ten cells for the State column at 80x24: the marks keep their symbol and a
    plain word, never a cut-off one ("≈ reconstruc") nor an identifier ("≈ fsc_hat")."""
    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await inject(pilot, "F1", 10, ("F1", "F13"))
        await settle(pilot)
        io = region_text(app, "#io")
        assert "≈ estimated" in io and io.count("⊘ masked") == 2 and "_hat" not in io
        assert "reconstruc" not in io and "(de" not in io
