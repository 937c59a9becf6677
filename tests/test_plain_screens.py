"""Plain words on every screen, not only in explanations: in the operator view (the default)
the panels, banners, alarm list and explanation name no internal identifier of the project
(GRAFCET steps, diagnoser states and labels, flags, estimates, filtered sensors, timers,
constraints, monitor labels, recovery procedures: tests/test_plain_words.identifiers); the
engineering view (E) shows them, says so in the status bar, and is journalled.

Each example project is run in the HMI in virtual time, normally and with a fault of its
own (a campaign fault or a scenario's injection), at 160×48 and 80×24.
"""

from __future__ import annotations

import asyncio
import re

import pytest
from ui_harness import region_text, run_for

from hmi.engine.scan import Engine
from hmi.explain.journal import read
from hmi.plant.sim.plant import SimPlant
from hmi.project.campaign import campaign_of
from hmi.project.injection import parse_injection
from hmi.project.kept import load_once
from hmi.project.scenarios import scenarios_of
from hmi.session.session import Session
from hmi.ui.app import PlcHmiApp
from hmi.ui.headless import press
from tests.conftest import PROJECTS
from tests.test_plain_words import PATTERNS, any_name, identifiers

# The operator's panels; the chronogram and the I/O table name I/O, the operator's words.
REGIONS = ("#status", "#banners", "#control", "#constraints", "#diagnosers", "#monitors",
           "#alarms", "#explain")
# a scan number is a count the operator may quote, not a name of the model
SCREEN_PATTERNS = tuple(p for p in PATTERNS if p != r"\bscan \d")


def faults(name: str) -> list[tuple[str, float]]:
    """A fault of the project's own, as injected from the command line, and how long to
    run: its campaign's first fault, or its first scenario with an injection."""
    project = load_once(PROJECTS / name)
    campaign = campaign_of(project)
    if campaign is not None and campaign.scenarios:
        s = campaign.scenarios[-1]
        device = f"{s.device}." if s.device else ""
        return [(f"{device}{s.fault}@{s.at_us}us", s.at_us / 1e6 + 12)]
    for scenario in scenarios_of(project):
        if scenario.injections:
            first = scenario.injections[0]
            return [(str(first), first.at_us / 1e6 + 12)]
    return []


CASES = [(name, None, 20.0) for name in sorted(p.name for p in PROJECTS.iterdir()
                                                if (p / "project.yaml").exists())]
CASES += [(name, fault, secs) for name, _, _ in CASES for fault, secs in faults(name)]


def make(name: str, inject: str | None) -> PlcHmiApp:
    project = load_once(PROJECTS / name)
    plant = SimPlant(project)
    if inject:
        plant.inject(parse_injection(inject))
    return PlcHmiApp(Session(Engine(project, plant)), live=False, show_measured=False)


def offences(text: str, names: set[str]) -> list[str]:
    import re
    found = [m.group(0) for p in SCREEN_PATTERNS for m in re.finditer(p, text)]
    if names and any_name(names).search(text):
        found += [n for n in names if re.search(rf"(?<![\w.]){re.escape(n)}(?!\w)", text)]
    return found


@pytest.mark.parametrize(("name", "inject", "secs"), CASES,
                         ids=[f"{n}-{f or 'normal'}" for n, f, _ in CASES])
def test_the_operator_view_names_no_internal_identifier(name, inject, secs):
    names = identifiers(load_once(PROJECTS / name))

    async def run():
        found: dict[str, list[str]] = {}
        for size in ((160, 48), (80, 24)):
            app = make(name, inject)
            async with app.run_test(size=size) as pilot:
                await run_for(pilot, secs)
                for level in range(3):  # the explanation opened down to its consequences
                    for region in REGIONS:
                        widget = app.query(region)
                        if not widget or not widget.first().display:
                            continue
                        hits = offences(region_text(app, region), names)
                        if hits:
                            found.setdefault(f"{size} {region}", []).extend(hits)
                    if level < 2:
                        await press(pilot, "e")
        return found
    found = asyncio.run(run())
    assert not found, found


def test_the_engineering_view_shows_the_names_says_so_and_is_journalled(tmp_path):
    from hmi.explain.journal import Journal
    from hmi.session.journal_recorder import JournalRecorder

    async def run():
        app = make("cispi_valve", "F13@10.4s")
        journal = tmp_path / "journal.jsonl"
        recorder = JournalRecorder(app.link.session, Journal(journal), "test")
        async with app.run_test(size=(80, 24)) as pilot:
            await run_for(pilot, 24)
            plain = region_text(app, "#control") + region_text(app, "#diagnosers")
            assert "ENG" not in region_text(app, "#status")
            await press(pilot, "E")
            await run_for(pilot, 0.1)
            assert "ENG" in region_text(app, "#status")
            engineering = region_text(app, "#control") + region_text(app, "#diagnosers")
            await press(pilot, "E")
            await run_for(pilot, 0.1)
            back = region_text(app, "#status")
        recorder.close()
        return plain, engineering, back, journal
    plain, engineering, back, journal = asyncio.run(run())
    # (the active step's id: which step is active at 24 s depends on the valve's timing)
    assert not re.search(r"\bX\d+\b", plain) and "A3" not in plain and "F13" not in plain
    assert re.search(r"\bX\d+\b", engineering) and "A3" in engineering and "F13" in engineering
    assert "ENG" not in back
    events = [e["event"] for e in read(journal).entries if e.get("type") == "action"]
    assert events[-2:] == ["engineering view", "operator view"]


async def _looked(app: PlcHmiApp, names: set[str], found: dict[str, list[str]],
                  what: str) -> None:
    """The whole screen as it is now (the panels, the banners, the SIMULATION strip, the
    message line, an open dialog) checked for the model's names."""
    from ui_harness import screen_text
    hits = offences(screen_text(app), names)
    if hits:
        found.setdefault(f"{app.size.width}x{app.size.height} {what}", []).extend(hits)


@pytest.mark.parametrize("size", [(160, 48), (80, 24)], ids=["160x48", "80x24"])
def test_dialogs_message_line_and_every_state_speak_plain_words(size):
    """The valve through its situations as an operator meets them: F13 (a diagnosis
    latched, the recovery needed), the fault injection dialog, the repair's answer, the
    fault reset dialog, the recovery's confirmation, recovery mode, leaving it, manual mode,
    a shelved alarm, the policy dialog; then safe blocking under `block` (latched) and its
    reset dialog. Every screen, dialogs included, names no internal identifier."""
    from ui_harness import palette, run_until
    from ui_scenarios import make_app

    from hmi.ui.dialogs import ChoiceDialog, ConfirmDialog
    from hmi.ui.fault_dialog import FaultDialog
    from hmi.ui.headless import wait_for_screen, wait_until
    names = identifiers(load_once(PROJECTS / "cispi_valve"))

    async def run() -> dict[str, list[str]]:
        found: dict[str, list[str]] = {}
        app = make_app(inject=("F13@10.4s",))
        async with app.run_test(size=size) as pilot:
            await run_until(pilot, lambda s: s.snapshot.recovery.needed, 20, "the recovery needed")
            await _looked(app, names, found, "diagnosis latched, recovery needed")
            await press(pilot, "f")
            await wait_for_screen(pilot, FaultDialog)
            await _looked(app, names, found, "fault dialog")
            await press(pilot, "escape")
            await palette(pilot, "SIMULATION: repair")
            await _looked(app, names, found, "repaired")
            await press(pilot, "r")
            await wait_for_screen(pilot, ConfirmDialog)
            await _looked(app, names, found, "reset dialog")
            await press(pilot, "g")
            await wait_until(pilot, lambda: app.screen.id == "recovery-dialog",
                             "the recovery dialog")
            await _looked(app, names, found, "recovery dialog")
            await press(pilot, "y")
            await run_for(pilot, 0.8)
            await _looked(app, names, found, "recovery running")
            await run_until(pilot, lambda s: s.snapshot.recovery.status == "done", 10,
                            "the recovery done")
            await _looked(app, names, found, "recovery done")
            await press(pilot, "r")
            await wait_for_screen(pilot, ConfirmDialog)
            await _looked(app, names, found, "reset dialog after the recovery")
            await press(pilot, "y")
            await run_for(pilot, 0.1)
            await _looked(app, names, found, "reset done")
            await press(pilot, "m")
            await wait_for_screen(pilot, ConfirmDialog)
            await _looked(app, names, found, "leave recovery dialog")
            await press(pilot, "y")
            await run_for(pilot, 3)
            await press(pilot, "m")
            await wait_for_screen(pilot, ConfirmDialog)
            await _looked(app, names, found, "manual dialog")
            await press(pilot, "y")
            await run_for(pilot, 1)
            await _looked(app, names, found, "manual mode")
            await press(pilot, "m", "y")
            await run_for(pilot, 1)
            alarm = next(a for a in app.link.last.alarms if not a.latched)
            app.shelve(alarm.key)
            await wait_for_screen(pilot, ChoiceDialog)
            await _looked(app, names, found, "shelve dialog")
            await press(pilot, "enter")
            await run_for(pilot, 0.1)
            await _looked(app, names, found, "an alarm shelved")
            await press(pilot, "p")
            await wait_for_screen(pilot, ChoiceDialog)
            await _looked(app, names, found, "policy dialog")
            await press(pilot, "escape")
        app = make_app(control="faulty", policy="block")
        async with app.run_test(size=size) as pilot:
            await run_until(pilot, lambda s: bool(s.snapshot.latched), 20, "safe blocking latched")
            await run_for(pilot, 0.5)
            await _looked(app, names, found, "safe blocking latched")
            await press(pilot, "r")
            await wait_for_screen(pilot, ConfirmDialog)
            await _looked(app, names, found, "reset dialog under safe blocking")
        return found
    found = asyncio.run(run())
    assert not found, found
