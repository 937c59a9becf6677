"""One soak session: the real app under Textual's pilot, in virtual time, step after step.

The app is the one operators run (:class:`~hmi.ui.app.PlcHmiApp`, every panel, dialog and
binding) on a :class:`~hmi.ui.driver.VirtualDriver`: scans run only when a ``run`` step says
so, as fast as the machine goes, so a session is exactly repeatable. The app reads the cell
through the runtime's protocol: in this process (:class:`~hmi.link.local.LocalLink`), or with
``split`` over the runtime's real Unix socket (:class:`~hmi.link.client.SocketLink` to a
:class:`~hmi.runtime.runtime.Runtime` in virtual time: its socket server and hub in threads
of their own, every frame and command encoded, sent and decoded, each ``run`` step an
``Advance``); either way the invariants listen to the runtime's session itself. The journal
is the real one (:class:`~hmi.session.journal_recorder.JournalRecorder`, to a file), told of
UI errors as in ``plchmi PROJECT``. After every step the invariants are checked
(hmi.soak.invariants); the session stops at the first broken one.

:func:`shrink` replays a failing step list without chunks of it, keeping every removal after
which the same invariant still breaks: what is left is a short list that reproduces it.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from textual.command import CommandInput, CommandList, CommandPalette
from textual.pilot import Pilot

from hmi.engine.build import EngineOptions, build_engine
from hmi.engine.commands import Command, CommandResult
from hmi.explain.journal import Journal
from hmi.history.historian import Historian
from hmi.history.target import Target
from hmi.project.loader import load_project
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.session import Session
from hmi.session.view import CellView
from hmi.soak.invariants import Broken, Invariants
from hmi.soak.operator import RandomOperator
from hmi.soak.steps import Click, Palette, Press, Resize, Row, Run, Step
from hmi.ui.app import PlcHmiApp
from hmi.ui.driver import VirtualDriver
from hmi.ui.headless import click, drain, press, settle, wait_for_screen
from hmi.ui.io_panel import IOPanel

MAX_STEPS_PER_MINUTE = 2000  # a guard: an operator that never lets time run still ends


@dataclass(frozen=True)
class SoakConfig:
    project: Path
    control: str | None = None
    size: tuple[int, int] = (80, 24)
    minutes: float = 30.0
    seed: int = 1
    max_steps: int | None = None  # a bound on the steps too (the CI's budget)
    split: bool = False  # the app attached over the runtime's socket (module docstring)


@dataclass
class SoakResult:
    config: SoakConfig
    steps: list[Step] = field(default_factory=list)  # done, in order (the failing one last)
    broken: list[Broken] = field(default_factory=list)
    scans: int = 0
    virtual_us: int = 0
    wall_s: float = 0.0
    gestures: Counter[str] = field(default_factory=Counter)  # step kinds, dialog answers
    commands: Counter[str] = field(default_factory=Counter)  # accepted commands by type
    refused: int = 0
    # why commands were refused ("Type: the cell's answer"): a seed whose operator is mostly
    # refused exercises little, and the summary says so instead of a bare count
    refusals: Counter[str] = field(default_factory=Counter)
    transitions: int = 0  # alarm state changes seen in the list (all found in the journal)
    raised: int = 0
    journal_lines: int = 0
    max_alarms: int = 0
    safe_state_violations: Counter[str] = field(default_factory=Counter)
    checks: Counter[str] = field(default_factory=Counter)  # invariant checks run, by kind
    skipped: int = 0  # palette entries not there (replays of a shrunk list)
    journal: Path | None = None

    @property
    def ok(self) -> bool:
        return not self.broken


def make_cell(config: SoakConfig, history: Path | None = None
              ) -> tuple[Session, Historian | None]:
    """The session the app shows (its scans in virtual time) and, with a `history` file,
    its historian: the trend screens then read a real history."""
    project = load_project(config.project)
    cell = Session(build_engine(project, options=EngineOptions(control=config.control)))
    historian = Historian(cell, Target("sqlite", str(history)), source="soak").attach() \
        if history is not None else None
    return cell, historian


def make_app(config: SoakConfig, history: Path | None = None
             ) -> tuple[PlcHmiApp, Session, Historian | None]:
    """The app, the session it shows (in this process) and its historian (make_cell)."""
    cell, historian = make_cell(config, history)
    return PlcHmiApp(cell, live=False, show_measured=False), cell, historian


class SplitCell:
    """The runtime of a soak over the socket (``split``): started on `cell` with its socket
    in `folder`, the app attached to it; stopped at the end (the screen leaves first).

    Virtual time is the soak's clock, not an operator's gesture: a ``run`` step goes as the
    screen's ``Advance`` while it is in control, and while it is not (the random operator
    released or handed control away) the scans run here and the step ends once the screen
    has the frame of the last one (waited for on that state)."""

    FINGERPRINT = "soak"
    HANG_S = 120.0  # a frame the runtime never sends: a hang, not a slow machine

    def __init__(self, cell: Session, folder: Path, journal: JournalRecorder):
        from hmi.link.client import SocketLink
        from hmi.runtime.runtime import Runtime
        from hmi.wire.messages import Identity
        self.cell = cell
        self.runtime = Runtime(cell, self.FINGERPRINT, folder / "runtime.sock", journal,
                               virtual=True)
        self.runtime.start()
        split = self

        class SoakLink(SocketLink):
            def advance(self, duration_us: int) -> int:
                return split.advance(duration_us)

        self.link = SoakLink(cell.project, folder / "runtime.sock", self.FINGERPRINT,
                             Identity("soak", "operator", "terminal", "soak"))
        self.link.first_frame.wait(self.HANG_S)

    def advance(self, duration_us: int) -> int:
        from hmi.link.client import SocketLink
        from hmi.link.local import advance
        link = self.link
        control = link.receiver.control
        if control is not None and control.holder is not None \
                and control.holder.id == link.client:
            return SocketLink.advance(link, duration_us)
        count = advance(self.cell, duration_us)
        last = self.cell.last
        started = time.monotonic()
        while last is not None and link.lost is None:
            view = link.view()
            if view is not None and view.cell.snapshot.scan >= last.snapshot.scan:
                break
            if time.monotonic() - started > self.HANG_S:
                raise RuntimeError(f"no frame of scan {last.snapshot.scan} within "
                                   f"{self.HANG_S:g} s")
            time.sleep(0.005)
        return count

    def stop(self) -> None:
        self.link.leave()
        self.runtime.stop("the soak ends")


async def session(config: SoakConfig, replay: list[Step] | None = None,
                  journal_dir: Path | None = None,
                  progress: Callable[[SoakResult], None] | None = None) -> SoakResult:
    """Run the random operator for `config.minutes` of virtual time (or replay `replay`).

    The journal goes to `journal_dir`, else to a temporary folder kept only if an invariant
    broke (its path is in the result)."""
    result = SoakResult(config)
    folder = Path(journal_dir or tempfile.mkdtemp(prefix="plchmi-soak-"))
    result.journal = folder / "journal.jsonl"
    split = None
    cell, historian = make_cell(config, folder / "history.sqlite")
    journal = JournalRecorder(cell, Journal(result.journal), "soak")
    if historian is not None:
        historian.hear(journal)
    if config.split:
        split = SplitCell(cell, folder, journal)
        app = PlcHmiApp(split.link, live=False, show_measured=False)
        app.containment.listeners.append(split.link.report_fault)  # the runtime journals
    else:
        app = PlcHmiApp(cell, live=False, show_measured=False)
        app.containment.listeners.append(journal.on_ui_fault)
    checker = Invariants(app, cell, result.journal)

    def count(command: Command, answer: CommandResult, view: CellView | None) -> None:
        if answer.accepted:
            result.commands[type(command).__name__] += 1
        else:
            result.refused += 1
            result.refusals[f"{type(command).__name__}: {answer.message}"] += 1
    cell.listeners.append(count)
    operator = RandomOperator(config.seed)
    limit_us = int(config.minutes * 60_000_000)
    max_steps = config.max_steps or max(100, int(config.minutes * MAX_STEPS_PER_MINUTE))
    started = time.perf_counter()
    try:
        async with app.run_test(size=config.size) as pilot:
            await settle(pilot)
            engine = cell.engine
            while True:
                if replay is not None:
                    if len(result.steps) >= len(replay):
                        break
                    step = replay[len(result.steps)]
                elif engine.now >= limit_us or len(result.steps) >= max_steps:
                    break
                else:
                    step = operator.next(app)
                result.gestures[_gesture(app, step)] += 1
                result.steps.append(step)
                if not await perform(pilot, step):
                    result.skipped += 1
                # the screen as the step left it is painted (a headless one is not by
                # itself, hmi.ui.driver): a widget that fails to draw breaks "exception"
                if VirtualDriver.paint(app):
                    await drain(pilot)
                if checker.check_step() or not app.is_running:
                    break
                if progress is not None and len(result.steps) % 50 == 0:
                    _fill(result, checker, cell, started)
                    progress(result)
    finally:
        if split is not None:
            split.stop()
        journal.close(None if checker.ok else str(checker.broken[0]))
        if historian is not None:
            historian.close()
    checker.check_journal()  # its last lines (the session's end)
    _fill(result, checker, cell, started)
    if journal_dir is None and result.ok:  # a passing session's journal is not kept
        shutil.rmtree(folder, ignore_errors=True)
        result.journal = None
    return result


def _fill(result: SoakResult, checker: Invariants, cell: Session, started: float) -> None:
    result.broken = list(checker.broken)
    result.scans = checker.scans
    result.virtual_us = cell.engine.now
    result.wall_s = time.perf_counter() - started
    result.transitions = checker.transitions
    result.raised = checker.raised
    result.journal_lines = checker.journal_lines
    result.max_alarms = checker.max_alarms
    result.safe_state_violations = Counter(checker.safe_state_violations)
    result.checks = Counter(checker.checks)


def _gesture(app: PlcHmiApp, step: Step) -> str:
    """What kind of gesture a step is, for the figures (dialog answers by dialog)."""
    screen = app.screen
    if isinstance(step, Press) and screen is not app.screen_stack[0]:
        return f"answer {screen.id or type(screen).__name__}: {step.keys[-1]}"
    return type(step).__name__.lower()


def _app(pilot: Pilot[Any]) -> PlcHmiApp:
    """The app a soak's pilot drives (always the HMI's, run headless)."""
    app = pilot.app
    assert isinstance(app, PlcHmiApp)
    return app


async def perform(pilot: Pilot[Any], step: Step) -> bool:
    """Do one step on the app; False if it could not be done (and nothing happened)."""
    app = _app(pilot)
    match step:
        case Run(us=us):
            driver = app.driver
            assert isinstance(driver, VirtualDriver)  # a soak runs in virtual time
            driver.advance(us)
        case Press(keys=keys):
            await press(pilot, *keys)
        case Palette(title=title):
            if not await palette_entry(pilot, title):
                await settle(pilot)
                return False
        case Row(name=name):
            if not await click_row(pilot, name):
                await settle(pilot)
                return False
        case Click(selector=selector, x=x, y=y):
            if not app.screen.query(selector) or not await click(pilot, selector, x, y):
                await settle(pilot)
                return False
        case Resize(width=width, height=height):
            await pilot.resize_terminal(width, height)
    await settle(pilot)
    return True


async def palette_entry(pilot: Pilot[Any], title: str) -> bool:
    """Open the palette, search for `title` and run the entry with exactly that title."""
    app = pilot.app
    if app.screen is not app.screen_stack[0]:
        return False  # a dialog is open: ctrl+p is not the main screen's
    await press(pilot, "ctrl+p")
    if not isinstance(app.screen, CommandPalette):
        return False
    screen = await wait_for_screen(pilot, CommandPalette)
    screen.query_one(CommandInput).value = title
    await drain(pilot)
    if VirtualDriver.paint(app):  # the hits as the operator sees them (drawn, tinted screen below)
        await drain(pilot)
    commands = screen.query_one(CommandList)
    for index in range(commands.option_count):
        prompt = commands.get_option_at_index(index).prompt
        plain = getattr(prompt, "plain", str(prompt))
        if plain.split("\n")[0].strip() == title:
            commands.highlighted = index
            await drain(pilot)
            await press(pilot, "enter")
            return True
    await press(pilot, "escape")
    return False


async def click_row(pilot: Pilot[Any], name: str) -> bool:
    """Click the I/O table's row of `name`, scrolled into view first (a mouse wheel)."""
    table = pilot.app.query_one(IOPanel)
    if pilot.app.screen is not pilot.app.screen_stack[0] or not table.region:
        return False
    try:
        index = table.get_row_index(name)
    except Exception:
        return False
    rows = table.scrollable_content_region.height - table.header_height
    if rows <= 0:
        return False
    if not table.scroll_y <= index < table.scroll_y + rows:
        table.scroll_to(y=max(0, index - rows // 2), animate=False, immediate=True)
        await drain(pilot)
    y = 1 + table.header_height + index - int(table.scroll_y)
    return await click(pilot, "#io", 3, y)


class ShrinkStopped(Exception):
    """A replay raised while shrinking: the shortest list found so far still reproduces the
    failure, so it is kept (with what raised) rather than lost with the whole shrink."""

    def __init__(self, best: list[Step], replays: int, error: BaseException):
        super().__init__(f"replay {replays} raised {what_raised(error)}")
        self.best, self.replays, self.error = best, replays, error


def what_raised(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


async def shrink(config: SoakConfig, steps: list[Step], invariant: str,
                 budget_s: float = 300.0, max_replays: int | None = None
                 ) -> tuple[list[Step], int]:
    """The shortest step list found within `budget_s` (and `max_replays` replays) that still
    breaks `invariant`, and the number of replays tried (ddmin: drop chunks, halving them
    when none can go). Bounded by replays alone (`budget_s` infinite), the result does not
    depend on the machine's speed: the soak farm's reports are the same wherever it ran.
    A replay that raises stops the shrink: :class:`ShrinkStopped` carries the best so far."""
    deadline = time.perf_counter() + budget_s
    replays = 0

    def out_of_budget() -> bool:
        return time.perf_counter() >= deadline or (max_replays is not None
                                                   and replays >= max_replays)

    async def breaks(candidate: list[Step]) -> list[Step] | None:
        nonlocal replays
        replays += 1
        with tempfile.TemporaryDirectory(prefix="plchmi-shrink-") as folder:
            result = await session(config, replay=candidate, journal_dir=Path(folder))
        if any(b.invariant == invariant for b in result.broken):
            return result.steps  # up to the failing step
        return None

    best = steps
    chunks = 2
    while len(best) > 1 and not out_of_budget():
        size = -(-len(best) // chunks)
        for start in range(0, len(best), size):
            if out_of_budget():
                break
            try:
                found = await breaks(best[:start] + best[start + size:])
            except Exception as exc:
                raise ShrinkStopped(best, replays, exc) from exc
            if found is not None:
                best = found
                chunks = max(chunks - 1, 2)
                break
        else:
            if size == 1:
                break
            chunks = min(len(best), chunks * 2)
    return best, replays
