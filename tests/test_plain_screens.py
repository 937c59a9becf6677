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
    assert "X1" not in plain and "A3" not in plain and "F13" not in plain
    assert "X1" in engineering and "A3" in engineering and "F13" in engineering
    assert "ENG" not in back
    events = [e["event"] for e in read(journal).entries if e.get("type") == "action"]
    assert events[-2:] == ["engineering view", "operator view"]
