"""The operator HMI (Textual). Reads a cell's views; sends commands through its link.

Data flows one way. The scans run elsewhere (the cell's runtime, or, in tests, in this
process: :mod:`hmi.link`), and the app knows the cell only through its
:class:`~hmi.link.base.CellLink`: at most ``REFRESH_HZ`` times a second it reads the link's
latest view, wraps it in a :class:`~hmi.ui.frame.Frame` and hands it down to every panel
(``show(frame)``). Panels post messages up; the app turns every operator action into a
command sent through :meth:`PlcHmiApp.send`, the single door to ``CellLink.command`` (where
the runtime's journal listens).

Screen regions (see ``app.tcss``): status bar and banners on top; the body in columns —
``#col-plant`` (I/O, and the constraints under it), ``#col-logic`` (control, and the
monitors under it), ``#col-time`` (chronogram) with the explanation panel beside it; the
alarm list under the body, with a height of its own so it is never squeezed; the simulation
strip, the message line and the footer close the screen.

The explanation panel explains the *subject*: the alarm selected in the alarm list, or a
situation picked from the palette or by clicking a constraint.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeVar, overload

from rich.text import Text
from textual import events
from textual.actions import ActionParseResult
from textual.app import App, ComposeResult, SystemCommand
from textual.binding import Binding
from textual.command import Provider
from textual.containers import Horizontal, Vertical
from textual.css.scalar import Unit
from textual.dom import DOMNode
from textual.screen import ModalScreen, Screen, ScreenResultCallbackType
from textual.widget import AwaitMount

from hmi.access import roles
from hmi.access.sessions import IdleTimer
from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    Command,
    CommandResult,
    CommentAlarm,
    EndRecovery,
    FaultReset,
    InjectFault,
    ManualOutput,
    Pause,
    ReleaseDevice,
    RepairFaults,
    Resume,
    SetInput,
    SetMode,
    SetPolicy,
    SetSpeed,
    SetView,
    Shelve,
    StartRecovery,
    StepScans,
    StopDevice,
    Unshelve,
    describe,
)
from hmi.engine.criteria import Wait
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.explain.alarms import Alarm
from hmi.explain.model import Explanation, Policy
from hmi.explain.plain import PlainNames
from hmi.explain.reset import ResetLine, reset_preview
from hmi.link.base import CellLink, ResetGuard, View
from hmi.link.local import LocalLink, SessionLink
from hmi.project.diagnosers import diagnosers_of
from hmi.project.injection import Injection
from hmi.project.model import POLICIES, ControlLaw
from hmi.project.monitors import monitors_of
from hmi.project.recovery import recoveries_of
from hmi.session.session import Session
from hmi.session.view import CellView
from hmi.timefmt import format_duration, seconds
from hmi.ui import manual
from hmi.ui.actions import ACTIONS, bindings
from hmi.ui.alarm_list import AlarmList, AlarmSelected
from hmi.ui.chronogram import WINDOWS_US, Chronogram
from hmi.ui.constraints_panel import ConstraintInfo, ConstraintsPanel
from hmi.ui.containment import ContainedPump, Containment, UIFault
from hmi.ui.diagnosers_panel import DiagnosersPanel, PartitionInfo
from hmi.ui.driver import LiveDriver, VirtualDriver
from hmi.ui.explain_panel import (
    ExplanationPanel,
    ExplanationShown,
    PolicyRequested,
    result_line,
)
from hmi.ui.fault_dialog import fault_words
from hmi.ui.footer import HmiFooter
from hmi.ui.frame import Frame, InjectedFault
from hmi.ui.grafcet_panel import GrafcetPanel, StepInfo, TimerInfo
from hmi.ui.io_panel import IOPanel
from hmi.ui.message_line import MessageLine, Words, result_text, spoken, verdict_text
from hmi.ui.messages import CommandRequested, ExplainRequested
from hmi.ui.monitors_panel import MonitorsPanel
from hmi.ui.panel import TOP_SHARE, ColumnPanel
from hmi.ui.presence import SILENT_S
from hmi.ui.reset import Asked, recovery_lines, reset_lines
from hmi.ui.serving import Served, gateway_lines, serving_lines
from hmi.ui.sim_panel import SimPanel
from hmi.ui.status import BannerStrip, StatusBar
from hmi.ui.style import ISA101, MUTED, OK_SYMBOL, Level, isa101_theme, tag
from hmi.ui.textual_adapter import LastResort
from hmi.ui.verdict import output_changes, request_verdict
from hmi.wire.messages import ClientInfo

if TYPE_CHECKING:
    from datetime import tzinfo

    from hmi.ui.palette import PaletteEntry
    from hmi.ui.trend_screen import TrendScreen

# The dialogs, the fault and signal pickers and the palette's provider are imported when
# first opened: the first frame shows none of them (docs/performance.md).

REFRESH_HZ = 20
SPEEDS: tuple[float | None, ...] = (1.0, 10.0, None)
POLICY_HELP = {
    "monitor": "report violations only; unsafe orders pass (commissioning)",
    "block": "on a violation, every output safe until a fault reset",
    "correct": "change the fewest outputs that satisfy every constraint",
}
RUN_STATE_COMMANDS = (Pause, Resume, StepScans, SetSpeed)
MANUAL_KEY_HELP = {
    True: "Manual: request the I/O table's highlighted output on",
    False: "Manual: request the I/O table's highlighted output off",
    None: "Manual: release the request on the I/O table's highlighted output",
}
MANUAL_KEYS = {"1": True, "0": False, "x": None}
SHELVE_TIMES = ((5 * 60_000_000, "5 min"), (15 * 60_000_000, "15 min"),
                (60 * 60_000_000, "1 h"), (8 * 3_600_000_000, "8 h (the longest)"))
WIDE = 120  # from this width on, the explanation panel stays beside the chronogram


def hmi_commands() -> type[Provider]:
    """The palette's provider of the HMI's commands (Textual asks when the palette opens)."""
    from hmi.ui.palette import HmiCommands
    return HmiCommands


class Body(ContainedPump, Vertical):
    """The panels' area. Its height changes with what is around it (an alarm row, a
    banner, the footer wrapping); the column panels size their detail on it."""

    def on_resize(self) -> None:
        app = self.app
        if isinstance(app, PlcHmiApp) and app.frame is not None:
            app._fit_plant_column()
        for panel in self.query(ColumnPanel):
            panel.recheck()


_R = TypeVar("_R")
_S = TypeVar("_S", bound=Screen[Any])


class _Shows(Protocol):
    """A panel the frame is handed to."""

    def show(self, frame: Frame) -> None: ...


class PlcHmiApp(LastResort, ContainedPump, App[None]):
    CSS_PATH = ["app.tcss", "dialogs.tcss", "trend.tcss"]
    TITLE = "plchmi"
    # 1 / 0 / x also from outside the I/O table (an explanation's policy button, the alarm
    # list): they act on the table's highlighted output; the table's own bindings come first
    # when it has the focus (the footer shows one of each).
    BINDINGS = [
        *bindings(),
        Binding("1", "manual_on", "On", tooltip=MANUAL_KEY_HELP[True]),
        Binding("0", "manual_off", "Off", tooltip=MANUAL_KEY_HELP[False]),
        Binding("x", "manual_release", "Release", tooltip=MANUAL_KEY_HELP[None]),
    ]
    COMMANDS = App.COMMANDS | {hmi_commands}
    HORIZONTAL_BREAKPOINTS = [(0, "-narrow"), (120, "-wide")]
    VERTICAL_BREAKPOINTS = [(0, "-short"), (40, "-tall")]

    def __init__(self, link: CellLink | Session, live: bool = True, *,
                 show_measured: bool | None = None, refresh_hz: float = REFRESH_HZ,
                 injected: tuple[Injection, ...] = (), bell: bool = False,
                 served: Served | None = None,
                 idle_clock: Callable[[], float] = time.monotonic):
        """`link`: the cell (a session given here runs in this process: the pilot tests and
        the single-process bench); `live`: its scans are paced by the wall clock and the
        screen refreshes on a timer, else whoever runs virtual time shows the frames."""
        super().__init__()
        cell: CellLink = LocalLink(link, live=live) if isinstance(link, Session) else link
        self.link = cell
        self.facts = cell.facts
        self.served = served  # the cell's OPC UA server (--opcua): its status is shown
        self.project = cell.project
        self.driver: LiveDriver | VirtualDriver = (LiveDriver(cell) if live
                                                   else VirtualDriver(cell))
        self.show_measured = live if show_measured is None else show_measured
        self.refresh_hz = refresh_hz
        self.history = cell.history  # every scan's edges and plant events (chronogram)
        self.stop_cell = False  # the operator quit and asked the cell to stop too
        self._asked: str | None = None  # the screen whose control request was asked
        self.frame: Frame | None = None
        self.frames_shown = 0  # frames handed to the panels (the UI refresh count)
        self._key: tuple[object, ...] | None = None  # what the last frame was made of
        self._version = 0  # bumped when something the frame shows changes outside the scan
        self.engineering = False  # the engineering view (E): internal names shown too
        self.answer = ""  # the last command's answer as the message line said it
        # the subject whose I/O rows were scrolled to, and the size then
        self._revealed: tuple[object, ...] | None = None
        self._stepping = False
        self._request: tuple[str, bool, int, str] | None = None  # pending manual verdict
        self._injected: list[InjectedFault] = []  # shown on the SIMULATION strip
        self._mode_commanded: str | None = None  # accepted SetMode, not yet in a snapshot
        self.free_inputs: tuple[str, ...] = self.facts.plant.free_inputs
        # What the explanation panel explains: the selected alarm, unless the operator picked
        # another situation (palette, a constraint clicked) since the selection last moved.
        self.subject: str | None = None
        # faults scheduled before the app started (plchmi ui --inject)
        self._injected += [InjectedFault(i, self._fault_text(i)) for i in injected]
        # --bell: the terminal bell on each new unacknowledged P1 alarm (optional)
        self.bell_on_p1 = bell
        self.bells = 0
        self._p1_unack: frozenset[str] = frozenset()
        # UI errors: contained and shown (banner, journal), or the reason the app ended
        self.containment = Containment(self._scan_time)
        if isinstance(cell, SessionLink):  # the recorder runs in this process's scans
            cell.on_recorder_error = self._recorder_failed
        # told once the first frame is on the screen (the start's caches save then)
        self.first_frame_listeners: list[Callable[[], None]] = []
        # The trends open (hmi.ui.trend_screen), told of every frame; the zone their times
        # are shown in (None: the machine's; the screenshots: UTC).
        self.trends: TrendScreen | None = None
        self.trend_zone: tzinfo | None = None
        self.set_class(True, f"-theme-{self.theme}", update=False)  # as a theme change sets
        # The idle lock of a screen people sign in to (the users file's idle-lock and
        # idle-warning, from the runtime): None where nobody signs in.
        lock_us = cell.idle_lock_us if cell.accountable else 0
        self.idle_timer: IdleTimer | None = IdleTimer(
            lock_us / 1e6, cell.idle_warning_us / 1e6, idle_clock) if lock_us > 0 else None
        self.idle_state = "active"  # active, warning, locked (what the screen shows)

    def get_css_variables(self) -> dict[str, str]:
        """The ISA-101 theme from the start: App.__init__ builds the stylesheet from these
        variables, so the theme is set before it does (without its watcher), not after, which
        parsed and applied every stylesheet a second time at each start (docs/performance.md).
        Both are dark themes: what App.__init__ set from the default theme before (the
        dark-mode class, the ANSI colour filter) holds for this one."""
        if ISA101 not in self.available_themes:
            self.register_theme(isa101_theme())
            self.set_reactive(App.theme, ISA101)
        return super().get_css_variables()

    # -- layout ------------------------------------------------------------------------------
    def _scan_time(self) -> tuple[int, int]:
        """The scan and time of the newest snapshot (where a UI error is placed)."""
        last = self.link.last
        return (last.snapshot.scan, last.snapshot.time_us) if last is not None else (0, 0)

    def _row_descriptions(self, descriptions: dict[str, str]) -> dict[str, str]:
        """The I/O table's Description cells: each without its device's name in front when
        the device is the same on every row (the valve: "closed end switch", not "Valve
        V1 closed end switch" cut to "Valve" at 80 columns); several devices keep theirs."""
        io = (*self.project.inputs, *self.project.outputs)
        devices = {v.device for v in io}
        if len(devices) != 1 or None in devices:
            return descriptions
        device = next(iter(devices))
        out = dict(descriptions)
        for v in io:
            text = v.description
            if device and text.lower().startswith(device.lower()):
                out[v.name] = text[len(device):].strip(" :-—,") or text
        return out

    def _wait_words(self, law: ControlLaw) -> Callable[[Wait], str] | None:
        """What a step waits for, in the words the explanations use."""
        if law.grafcet is None:
            return None
        from hmi.explain.context import ExplanationContext
        from hmi.explain.sequence import wait_words
        context, grafcet = ExplanationContext(self.project), law.grafcet
        return lambda wait: wait_words(context, grafcet, wait)

    def compose(self) -> ComposeResult:
        facts = self.facts
        project = self.project
        # the I/O's, and the estimates' (an I/O row says "≈ estimated open position")
        descriptions = {v.name: v.description for v in (*project.inputs, *project.outputs)}
        descriptions |= {t.name: t.description for t in project.timers}
        descriptions |= {o.name: o.description for o in project.observers}
        law = project.controls[facts.control]
        steps = [StepInfo(s.name, s.description) for s in law.grafcet.steps] \
            if law.grafcet else []
        timers = [TimerInfo(t.name, t.kind, t.description) for t in project.timers]
        default_signals = tuple(s.name for s in self.history.signals
                                if s.kind in ("output", "input"))
        timer_signals = tuple(s.name for s in self.history.signals if s.kind == "timer")
        constraints = [ConstraintInfo(c.name, c.kind, c.expr.source, c.description)
                       for c in project.constraints]
        diagnosers = diagnosers_of(project)
        plain = PlainNames(project)
        partitions = {p.flag: PartitionInfo(
            p.flag, p.sensor, p.estimate, p.actuators, p.description or "",
            plain.name(p.sensor) if p.sensor else "",
            tuple(plain.name(a) for a in p.actuators))
            for spec in diagnosers for p in spec.partitions}
        yield StatusBar(id="status")
        yield BannerStrip(id="banners")
        with Body(id="body"):
            with Horizontal(id="top"):
                with Vertical(id="col-plant"):
                    yield IOPanel(facts.layout, descriptions, self.free_inputs, id="io",
                                  row_descriptions=self._row_descriptions(descriptions),
                                  devices={v.name: v.device for v in project.outputs
                                           if v.device},
                                  partitions=tuple(partitions.values()))
                    yield ConstraintsPanel(constraints, id="constraints")
                with Vertical(id="col-logic"):
                    yield GrafcetPanel(facts.control, steps, timers, id="control",
                                       words=self._wait_words(law))
                    yield DiagnosersPanel(partitions, len(diagnosers), id="diagnosers")
                    yield MonitorsPanel(len(monitors_of(project)), id="monitors")
            with Horizontal(id="bottom"):
                with Vertical(id="col-time"):
                    yield Chronogram(self.history, default_signals, engineering=timer_signals,
                                     id="chronogram")
                yield ExplanationPanel(id="explain")
        yield AlarmList(id="alarms")
        yield SimPanel(self.history, id="sim")
        yield MessageLine(id="message")
        yield HmiFooter(compact=True)

    def on_mount(self) -> None:
        # the panels that set their own height first (banners, alarm rows): the column
        # panels measure their room after them
        self._views: list[_Shows] = [self.query_one(StatusBar), self.query_one(BannerStrip),
                       self.query_one(AlarmList), self.query_one(IOPanel),
                       self.query_one(ConstraintsPanel), self.query_one(GrafcetPanel),
                       self.query_one(DiagnosersPanel), self.query_one(MonitorsPanel),
                       self.query_one(Chronogram), self.query_one(SimPanel)]
        # kept, not queried per frame: cheaper, and a frame during shutdown finds them
        self._alarm_list = self.query_one(AlarmList)
        self._explanation = self.query_one(ExplanationPanel)
        self._col_time = self.query_one("#col-time")
        self.query_one(IOPanel).focus()
        self.message.say(Text("ctrl+p: all commands", style=MUTED))
        self.poll(force=True)
        if self.driver.live:
            self.set_interval(1 / self.refresh_hz, self.poll)
            if self.idle_timer is not None:
                self.set_interval(1.0, self.check_idle_lock)
        # else: in virtual time (tests, screenshots, the soak) whoever runs the scans shows
        # the frames (hmi.ui.headless.settle); a refresh paced by the wall clock would make
        # what a test sees depend on the machine's load
        # Start scanning once the first screen is drawn: the first layout is the heaviest
        # thing the UI does and would otherwise make the first scans late.
        self.call_after_refresh(self._first_frame_shown)

    def _first_frame_shown(self) -> None:
        self.driver.start()
        for listener in self.first_frame_listeners:
            listener()

    def on_unmount(self) -> None:
        self.driver.stop()

    # -- fault containment (see hmi.ui.containment) ------------------------------------------
    def _recorder_failed(self, exc: BaseException) -> None:
        """The scan recorder failed in this process's scan thread (the scan goes on)."""
        self.containment.record("the UI's scan recorder", exc)

    def contain(self, what: str, exc: BaseException) -> UIFault:
        """An error in the UI: remembered, shown (banner, message line), journalled; the
        screen goes on refreshing and the scan never noticed."""
        fault = self.containment.record(what, exc)
        try:
            line = tag("UI ERROR", Level.ALARM)
            line.append(f" {fault.summary} · details: {fault.report}")
            self.message.say(line)
        except Exception:
            pass  # the banner says it at the next frame
        return fault

    def guarded(self, what: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """`function`, with its errors contained (dialog answers, palette entries)."""
        def run(*args: Any) -> Any:
            try:
                return function(*args)
            except Exception as exc:
                self.contain(what, exc)
                return None
        return run

    def last_resort(self, error: Exception) -> None:
        """Textual's last resort (an error in its own widgets or the compositor): the app
        cannot go on. Remembered as the reason of an abnormal end, then Textual ends it."""
        self.containment.record("the HMI (Textual)", error, fatal=True)

    async def run_action(self, action: str | ActionParseResult,
                         default_namespace: DOMNode | None = None,
                         namespaces: Mapping[str, DOMNode] | None = None) -> bool:
        """Every key's and palette's action goes through here: an error in it is contained."""
        try:
            return await super().run_action(action, default_namespace, namespaces)
        except Exception as exc:
            self.contain(f"action {action}", exc)
            return True

    def get_default_screen(self) -> Screen[Any]:
        """The main screen; like every screen (get_screen: the dialogs, the palette), in
        virtual time it is drawn at rest, never by the wall clock (VirtualDriver.hold)."""
        screen = super().get_default_screen()
        if isinstance(self.driver, VirtualDriver):
            self.driver.hold(screen)
        return screen

    @overload
    def get_screen(self, screen: _S) -> _S: ...
    @overload
    def get_screen(self, screen: str) -> Screen[Any]: ...
    @overload
    def get_screen(self, screen: str, screen_class: type[_S] | None = None) -> _S: ...
    @overload
    def get_screen(self, screen: _S, screen_class: type[_S] | None = None) -> _S: ...

    def get_screen(self, screen: Screen[Any] | str,
                   screen_class: type[Screen[Any]] | None = None) -> Screen[Any]:
        found = super().get_screen(screen, screen_class)
        if isinstance(self.driver, VirtualDriver):
            self.driver.hold(found)
        return found

    def delay_update(self, delay: float = 0.05) -> None:
        """Textual masks some transitions (the palette closing) by holding every paint for
        `delay` s of wall clock; in virtual time the screen is drawn at rest anyway, and a
        wait on the wall clock would make a test spin until it ends."""
        if self.driver.live:
            super().delay_update(delay)

    @overload
    def push_screen(self, screen: Screen[_R] | str,
                    callback: ScreenResultCallbackType[_R] | None = None,
                    wait_for_dismiss: Literal[False] = False, *,
                    mode: str | None = None) -> AwaitMount: ...
    @overload
    def push_screen(self, screen: Screen[_R] | str,
                    callback: ScreenResultCallbackType[_R] | None = None,
                    wait_for_dismiss: Literal[True] = True, *,
                    mode: str | None = None) -> asyncio.Future[_R]: ...

    def push_screen(self, screen: Screen[_R] | str,
                    callback: ScreenResultCallbackType[_R] | None = None,
                    wait_for_dismiss: bool = False, *,
                    mode: str | None = None) -> AwaitMount | asyncio.Future[_R]:
        """Dialogs: the answer's handling is contained like any other action."""
        if callback is not None:
            callback = self.guarded(f"answer to {getattr(screen, 'id', None) or screen}",
                                    callback)
        if wait_for_dismiss:
            return super().push_screen(screen, callback, True, mode=mode)
        return super().push_screen(screen, callback, False, mode=mode)

    @property
    def message(self) -> MessageLine:
        return self.query_one(MessageLine)

    @property
    def chronogram(self) -> Chronogram:
        return self.query_one(Chronogram)

    # -- the display loop --------------------------------------------------------------------
    def run_label(self, view: View | None = None) -> str:
        view = view or self.link.view()
        label = view.run.label if view is not None else "paused"
        if label == "paused" and self._stepping:
            return "stepping"
        return label

    @property
    def running(self) -> bool:
        """The cell's scans run (not paused), as of the latest view."""
        view = self.link.view()
        return view is not None and view.run.running

    def poll(self, force: bool = False) -> bool:
        """Show the latest snapshot if anything changed; True if a frame was handed down.

        The snapshot comes with the history of that same scan (a view: never the newest
        snapshot then the history, which may be a scan newer)."""
        try:
            return self._poll(force)
        except Exception as exc:  # the frame itself could not be built
            self.contain("the screen refresh", exc)
            return False

    def _poll(self, force: bool) -> bool:
        self._check_driver()
        view = self.link.view()
        if view is None:
            return False
        cell = view.cell
        snap = cell.snapshot
        run = self.run_label(view)
        if self._mode_commanded == snap.mode:
            self._mode_commanded = None
        contained = self.containment
        frame_faults = contained.version
        serving = self.served.status() if self.served is not None else None
        gateway = next((s for s in view.services if s.name == "opcua"), None)
        overruns = self.driver.overruns
        lost = self.link.lost
        silent = self.link.silent_s()
        silent = float(int(silent)) if silent >= SILENT_S else 0.0
        key = (snap.scan, id(cell), run, view.run.speed, overruns, view.control, lost,
               silent, self._version, self._mode_commanded, contained.version, serving,
               gateway)
        if not force and key == self._key:
            return False
        self._key = key
        frame = Frame(
            cell=cell, run=run, speed=view.run.speed, live=self.driver.live,
            project=self.project.name, show_measured=self.show_measured,
            overruns=overruns, changed=output_changes(snap, self.engineering),
            injected=tuple(self._injected), free_inputs=self.free_inputs,
            damage_count=view.damage_count, mode_commanded=self._mode_commanded,
            constraints=view.constraints, ui_fault=contained.latest,
            ui_faults=contained.total, serving=serving, gateway=gateway,
            control=view.control,
            me=self.link.client, lost=lost, silent_s=silent,
            engineering=self.engineering)
        self._show_presence(frame)
        self.frame = frame
        for panel in self._views:  # one panel failing leaves the others showing this frame
            try:
                panel.show(frame)
            except Exception as exc:
                self.contain(f"{type(panel).__name__} refresh", exc)
        try:
            self._fit_plant_column()
            if len(self.screen_stack) > 1:
                from hmi.ui.dialogs import keep_clear
                keep_clear(self)
        except Exception as exc:
            self.contain("plant column layout", exc)
        self._ring(cell)
        trends = self.trends
        if trends is not None:
            try:
                trends.tick(self._history_now(snap))
            except Exception as exc:
                self.contain("the trends' refresh", exc)
        try:
            self._explain(frame)
        except Exception as exc:
            self.contain("ExplanationPanel refresh", exc)
        if contained.version != frame_faults:
            self._show_faults(frame)
        self._judge_request(snap)
        self.frames_shown += 1
        return True

    # -- among the cell's screens (hmi.ui.presence) --------------------------------------
    def _show_presence(self, frame: Frame) -> None:
        """The runtime lost (the screen dimmed: nothing is live), and control changing hands:
        said on the message line; a request from another screen asked in a dialog."""
        gone = bool(frame.lost or frame.silent_s)
        if self.has_class("-lost") != gone:
            self.set_class(gone, "-lost")
        if frame.lost and (self.frame is None or not self.frame.lost):
            self.message.say(tag(f"RUNTIME LOST: {frame.lost}", Level.ALARM))
        before = self.frame.control if self.frame is not None else None
        now = frame.control
        if now is None or frame.lost:
            return
        me = frame.me
        had = before is not None and before.holder is not None and before.holder.id == me
        has = now.holder is not None and now.holder.id == me
        if had and not has:
            who = f"{now.holder} is in control now" if now.holder else "nobody is in control"
            self.message.say(tag(f"{who}: this screen's commands are refused until it has "
                                 "control again", Level.ATTENTION))
        elif has and not had and before is not None:
            self.message.say(Text(f"{OK_SYMBOL} this screen is in control"))
        asked = now.asked_by
        if has and asked is not None and asked.id != self._asked:
            self._asked = asked.id
            self._ask_hand_over(asked)
        elif asked is None:
            self._asked = None

    def _ask_hand_over(self, asked: ClientInfo) -> None:
        from hmi.ui.dialogs import ConfirmDialog
        who = asked

        def answered(yes: bool | str | None) -> None:
            result = self.link.hand_over(asked.id if yes else "")
            self.message.say(result_text(
                f"control handed over to {who}" if yes else "control kept", result))
        self.push_screen(ConfirmDialog(
            f"{who.identity.user} asks for control", [
                f"{who} asks to take control of the cell.",
                "y: hand control over — this screen's commands are refused from then on;",
                "n: keep it — they are told you kept it, and may take it over anyway."],
            "Hand over", dialog_id="control-request"), answered)

    def request_control(self) -> None:
        result = self.link.request_control()
        self.message.say(result_text("request control", result))

    def take_control(self) -> None:
        from hmi.ui.dialogs import ConfirmDialog
        view = self.link.view()
        holder = view.control.holder if view is not None and view.control else None
        lines: list[Text | str] = ["This screen takes control of the cell without waiting "
                                   "for an answer."]
        if holder is not None:
            lines.append(f"{holder} loses it at once; their commands are refused from "
                         "then on, and they are told.")

        def answered(yes: bool | str | None) -> None:
            if yes:
                self.message.say(result_text("take control", self.link.take_control()))
            else:
                self.message.say(Text("cancelled: take control", style=MUTED))
        self.push_screen(ConfirmDialog("Take control over?", lines, "Take control",
                                       dialog_id="control-take"), answered)

    def release_control(self) -> None:
        self.message.say(result_text("release control", self.link.release_control()))

    def hand_over(self, to: str, who: str) -> None:
        self.message.say(result_text(f"hand control over to {who}", self.link.hand_over(to)))

    def _control_entries(self) -> list[PaletteEntry]:
        """Control among several screens: request, take over, release, hand over."""
        from hmi.ui.palette import PaletteEntry
        view = self.link.view()
        control = view.control if view is not None else None
        if control is None or self.link.client is None or self.link.lost:
            return []
        if not self.link.identity.may_command:
            return []
        holder = control.holder
        if holder is None or holder.id != self.link.client:
            held = f" from {holder}" if holder else ""
            return [PaletteEntry("Control: request it", "Granted at once if nobody holds it; "
                                 f"else {holder or 'the holder'} is asked",
                                 self.request_control),
                    PaletteEntry(f"Control: take it over{held}…", "Without waiting for an "
                                 "answer (confirmed first)", self.take_control)]
        entries = [PaletteEntry("Control: release it", "Nobody is in control until a "
                                "screen takes it", self.release_control)]
        for client in control.clients:
            if client.id != self.link.client and client.identity.may_command:
                entries.append(PaletteEntry(
                    f"Control: hand over to {client}", f"screen {client.id}",
                    partial(self.hand_over, client.id, str(client))))
        return entries

    def _ring(self, cell: CellView) -> None:
        """The bell, once per P1 alarm that became active and unacknowledged since the last
        frame (a returning one counts again); nothing without --bell."""
        now = frozenset(a.key for a in cell.alarms
                        if a.priority == 1 and a.state == "active-unacknowledged")
        new = now - self._p1_unack
        self._p1_unack = now
        if new and self.bell_on_p1:
            self.bells += 1
            self.bell()

    def _fit_plant_column(self) -> None:
        """The constraints panel first, the I/O table the rest: the I/O table takes at most
        what the upper row leaves once the constraints panel has its rows (violated ones
        first), so a violated constraint is on screen at every size from 80x24 (a long I/O
        table scrolls instead)."""
        body = self.query_one(Body)
        if not body.size.height:
            return
        constraints = self.query_one(ConstraintsPanel)
        io = self.query_one(IOPanel)
        io_least = 4  # its border, the header and one row
        io_wanted = min(io.row_count + 3, 14)
        border = 1 if constraints.has_class("-compact") else 2
        cap = 12 if self.size.height >= 40 else 6
        wanted = min(constraints.wanted_lines() + border, cap)
        needed = min(constraints.needed_lines() + border, cap)
        # The upper row takes 60 % of the body, more when the I/O and the violated
        # constraints need it, as long as the chronogram keeps its least (#bottom's
        # min-height, 5 lines).
        height = body.size.height
        top = max(int(height * TOP_SHARE), min(height - 5, io_wanted + needed))
        row = self.query_one("#top")
        if row.styles.max_height is None or row.styles.max_height.value != top or \
                row.styles.max_height.unit != Unit.CELLS:
            row.styles.max_height = top
        panel = min(max(needed, min(wanted, top - io_wanted)), max(top - io_least, 2))
        if constraints.styles.max_height is None or constraints.styles.max_height.value != panel:
            constraints.styles.max_height = panel
        limit = max(io_least, min(top - panel, io_wanted))
        if io.styles.max_height is None or io.styles.max_height.value != limit:
            io.styles.max_height = limit

    def _show_faults(self, frame: Frame) -> None:
        """A panel failed while this frame was shown: the banner and the status bar say so in
        this same frame (not at the next refresh, which a paused app may never have)."""
        contained = self.containment
        self.frame = frame = replace(frame, ui_fault=contained.latest,
                                     ui_faults=contained.total)
        self._key = (*self._key[:-1], contained.version) if self._key else None
        for view in self._views[:2]:  # the status bar and the banners
            try:
                view.show(frame)
            except Exception as exc:
                self.contain(f"{type(view).__name__} refresh", exc)

    def _check_driver(self) -> None:
        """The scan thread died (a scan listener failed): nothing scans any more, so the HMI
        cannot go on. An abnormal end (see hmi.cli.ui.cmd_ui: safe outputs on a real plant)."""
        error = getattr(self.driver, "error", None)
        if error is not None and self.containment.fatal is None:
            self.containment.record("the scan thread", error, fatal=True)
            self.exit(return_code=1)

    def _judge_request(self, snap: Snapshot) -> None:
        if self._request is None:
            return
        name, requested, scan, what = self._request
        if snap.scan <= scan:
            return
        self._request = None
        if snap.mode != "manual":
            return  # left manual mode before a scan ran the request
        device = next((o.device for o in self.project.outputs if o.name == name), None)
        ok, line = request_verdict(snap, name, requested, device, self.engineering)
        self.message.say(verdict_text(ok, f"{what} → {line}"))

    # -- the explanation's subject -----------------------------------------------------------
    @property
    def alarm_list(self) -> AlarmList:
        return self._alarm_list

    @property
    def explanation_panel(self) -> ExplanationPanel:
        return self._explanation

    def _explain(self, frame: Frame) -> None:
        """Hand the subject's explanation to the panel (the current one, else the alarm's
        last: a cleared alarm still explains what happened until it is acknowledged)."""
        cell = frame.cell
        key = self.subject or self.alarm_list.selected
        explanation = next((e for e in cell.explanations if e.key == key), None)
        alarm = next((a for a in cell.alarms if a.key == key), None)
        if explanation is None and alarm is not None:
            explanation = alarm.explanation
        if explanation is None and key != self.alarm_list.selected:
            self.subject = None  # the situation picked is over: back to the selected alarm
            key = self.alarm_list.selected
            explanation = next((e for e in cell.explanations if e.key == key), None)
            alarm = next((a for a in cell.alarms if a.key == key), None)
            if explanation is None and alarm is not None:
                explanation = alarm.explanation
        self.explanation_panel.show(key if explanation else None, explanation, alarm,
                                    self.size.width >= WIDE)
        revealed = (explanation.key if explanation else None, self.size)
        if explanation is not None and revealed != self._revealed:
            self._revealed = revealed  # once per subject (and size): the operator may scroll
            self.query_one(IOPanel).reveal_subject(self._subject_rows(explanation))

    def _subject_rows(self, explanation: Explanation) -> list[str]:
        """The I/O rows a situation is about: a constraint's signals (a filtered sensor as
        its sensor), else its device's I/O, those the State column marks first (an estimated
        sensor, a masked or changed order: at 80x24 the valve's F13 showed fsc, fso and C,
        and not the masked open order)."""
        project = self.project
        if explanation.key.startswith("constraint:"):
            name = explanation.key.split(":", 1)[1]
            constraint = next((c for c in project.constraints if c.name == name), None)
            if constraint is not None:
                sensors = {p.filtered: p.sensor for spec in project.diagnosers
                           for p in spec.partitions if p.filtered and p.sensor}
                names = [sensors.get(lit.name, lit.name) for lit in constraint.literals]
                return [*constraint.outputs, *names]  # what it blocks first
        rows = [v.name for v in (*project.inputs, *project.outputs)
                if v.device == explanation.device]
        frame = self.frame
        if frame is None:
            return rows
        snap = frame.snapshot  # the rows marked now first: estimated, masked, changed
        marked = {*snap.reconstructed, *snap.masked, *frame.changed}
        return sorted(rows, key=lambda name: name not in marked)

    def on_alarm_selected(self, message: AlarmSelected) -> None:
        self.subject = None
        if self.frame is not None:
            self._explain(self.frame)
        panel = self.explanation_panel
        if message.open and panel.key is not None and panel.level < 2:
            panel.open_to(2)

    def on_explain_requested(self, message: ExplainRequested) -> None:
        self.explain(message.key, message.open_level)

    def explain(self, key: str, open_level: int = 2) -> None:
        """Explain `key` (select its alarm when it has one) and open it to `open_level`."""
        cell = self.link.last
        if cell is None:
            return
        if not any(e.key == key for e in cell.explanations) and \
                not any(a.key == key for a in cell.alarms):
            self.message.say(Text(f"nothing to explain for {key} now", style=MUTED))
            return
        if not self.alarm_list.select(key):
            self.subject = key
        else:
            self.subject = None
        if self.frame is not None:
            self._explain(self.frame)
        panel = self.explanation_panel
        if panel.key == key and panel.level < open_level:
            panel.open_to(open_level)

    def on_explanation_shown(self, message: ExplanationShown) -> None:
        self._place_chronogram()

    def _place_chronogram(self) -> None:
        """Narrow screens: an open explanation takes the chronogram's place; wide ones show
        both (again, after a resize from narrow to wide)."""
        chrono = self._col_time
        show = self.size.width >= WIDE or not self._explanation.visible
        if chrono.display != show:
            chrono.display = show

    def on_resize(self) -> None:
        # Textual sets the app's new size after this handler: look once it is set
        self.call_later(self._resized)

    def _resized(self) -> None:
        if self.frame is not None and hasattr(self, "_explanation"):
            self._explain(self.frame)
            self._place_chronogram()

    def on_policy_requested(self, message: PolicyRequested) -> None:
        self.choose_policy(message.key, message.policy)

    def choose_policy(self, key: str, policy: Policy,
                      asked: Asked | None = None) -> None:
        """A policy button (or its palette entry): confirmed if it changes what the plant
        does, then sent as ChoosePolicy; its answer is shown in the panel at once. A fault
        reset's is sent only if it still does what its dialog said (`asked`: the dialog the
        operator confirmed before, when asked again; see :meth:`_reset_if_unchanged`)."""
        from hmi.ui.dialogs import ConfirmDialog
        if policy.command is None:
            self._choose(key, policy, True)
            return
        cell = self.link.last
        shown = reset_preview(cell.snapshot, cell.alarms) \
            if cell and isinstance(policy.command, FaultReset) else None
        title, lines, level = self._policy_confirmation(key, policy, cell, asked)

        def answered(yes: bool | None) -> None:
            if yes and shown is not None and cell is not None:
                result = self._reset_if_unchanged(
                    ChoosePolicy(key, policy.id), shown, cell.snapshot,
                    partial(self.choose_policy, key, policy))
                if result is not None:
                    self._said(key, policy, result)
            else:
                self._choose(key, policy, yes)
        self.push_screen(ConfirmDialog(title, lines, policy.label, level=level,
                                       dialog_id="policy-choice"), answered)

    def _choose(self, key: str, policy: Policy, yes: bool | None) -> None:
        if not yes:
            self.message.say(Text(f"cancelled: {policy.label} — {self._situation_text(key)}",
                                  style=MUTED))
            return
        self.act(ChoosePolicy(key, policy.id), partial(self._said, key, policy))

    def _said(self, key: str, policy: Policy, result: CommandResult) -> None:
        self.explanation_panel.say_result(key, result_line(key, policy, result.accepted,
                                                           self.answer))

    def _policy_confirmation(self, key: str, policy: Policy, cell: CellView | None,
                             asked: Asked | None = None
                             ) -> tuple[str, list[Text | str], Level]:
        explanation = next((e for e in cell.explanations if e.key == key), None) \
            if cell else None
        snap = cell.snapshot if cell else None
        lines: list[Text | str] = []
        if explanation is not None:
            lines.append(Text(f"For: {explanation.what}", style=MUTED))
        if not isinstance(policy.command, StopDevice):  # (said in full below)
            lines.append(f"{policy.label}: {policy.effect}.")
        level = Level.ATTENTION
        match policy.command:
            case FaultReset():
                lines += reset_lines(cell, asked, self.engineering) if cell else []
            case SetMode(manual=True):
                lines += self._manual_lines(snap) if snap else []
            case SetMode(manual=False):
                lines.append("Every manual request is released.")
                lines += self._leave_manual_lines(snap) if snap else []
            case StartRecovery(procedure=name):
                spec = next((p for p in recoveries_of(self.project) if p.name == name), None)
                if spec is not None:
                    lines += recovery_lines(self.project, spec, self.engineering)
                level = Level.ALARM
            case EndRecovery():
                lines.append("The control program starts again from its initial steps.")
            case StopDevice(device=device):
                outputs = ", ".join(v.name for v in self.project.outputs
                                    if v.device == device)
                lines += [f"Every output of {device} ({outputs}) is held at its safe value "
                          "until you release it;",
                          "the control program keeps running and the rest of the cell goes "
                          "on.",
                          f"To release it: ctrl+p, Release device {device}."]
                level = Level.ALARM
            case SetPolicy(policy=name):
                lines.append(f"The safety filter switches to {name}: {POLICY_HELP[name]}.")
        return f"{policy.label}?", lines, level

    # -- sending commands --------------------------------------------------------------------
    def send(self, command: Command, reason: str = "", password: str = "") -> CommandResult:
        """The one place operator actions leave the UI: through ``Session.command``."""
        if reason or password:
            answer = self.link.command(command, reason=reason, password=password)
        else:
            answer = self.link.command(command)
        return self._sent(command, answer.result)

    def act(self, command: Command,
            then: Callable[[CommandResult], None] | None = None) -> None:
        """A command the operator chose: sent at once, or where the runtime asks it (people
        sign in to it: ``link.accountable``) once its reason is given — and for the
        riskiest, the password again (hmi.access.roles: needs_reason, needs_password; an
        explanation's policy as what it carries out). Cancelled: nothing is sent, and the
        message line says so. `then` hears the answer."""
        done = then or (lambda result: None)
        carried = command
        if isinstance(command, ChoosePolicy):
            carried = self._policy_command(command.key, command.policy) or command
        if not (self.link.accountable and roles.needs_reason(carried)):
            done(self.send(command))
            return
        from hmi.ui.dialogs import ReasonDialog

        def given(answer: tuple[str, str] | None) -> None:
            if answer is None:
                self.message.say(Text(f"cancelled: {describe(carried)} (nothing sent)",
                                      style=MUTED))
                return
            done(self.send(command, reason=answer[0], password=answer[1]))
        self.push_screen(ReasonDialog(describe(carried), roles.needs_password(carried)),
                         given)

    def _sent(self, command: Command, result: CommandResult,
              reset_shown: list[ResetLine] | None = None) -> CommandResult:
        """What the UI makes of a command's answer: the message line, the commanded mode.
        `reset_shown`: a fault reset's preview the operator confirmed (and the engine found
        unchanged): the answer in its plain words, not the engine's names."""
        what = describe(command)
        inner = None
        if isinstance(command, ChoosePolicy):  # the policy's answer in that command's words
            inner = FaultReset() if reset_shown is not None else \
                self._policy_command(command.key, command.policy)
        said, answer = spoken(command, result, self._situation_text,
                              None if self.engineering else Words(self._fault_text,
                                                                  reset_shown,
                                                                  self._step_words(), inner))
        self.answer = answer
        text = result_text(said, result, answer)
        match command:
            case Pause() | Resume():
                self._stepping = False
            case StepScans():
                self._stepping = self._stepping or result.accepted
            case ManualOutput(name=name, value=value) if result.accepted:
                last = self.link.last
                self._request = (name, bool(value), last.snapshot.scan if last else 0, what)
            case SetMode(manual=manual) if result.accepted:
                self._mode_commanded = "manual" if manual else "auto"
            case StartRecovery() if result.accepted:
                self._mode_commanded = "recovery"
            case EndRecovery() if result.accepted:
                self._mode_commanded = "auto"
            case ChoosePolicy(key=key, policy=policy_id) if result.accepted:
                inner = self._policy_command(key, policy_id)
                if isinstance(inner, SetMode):
                    self._mode_commanded = "manual" if inner.manual else "auto"
                elif isinstance(inner, StartRecovery):
                    self._mode_commanded = "recovery"
                elif isinstance(inner, EndRecovery):
                    self._mode_commanded = "auto"
            case InjectFault(injection=injection) if result.accepted:
                self._injected.append(InjectedFault(injection, self._fault_text(injection)))
                self._version += 1
            case RepairFaults(device=device) if result.accepted:
                self._injected = [f for f in self._injected
                                  if device is not None and f.injection.device not in
                                  (None, device)]
                self._version += 1
                self.explanation_panel.forget_results()
            case FaultReset() if result.accepted:
                self.explanation_panel.forget_results()  # what they answered has changed
            case SetView(engineering=engineering) if result.accepted:
                self.engineering = engineering
                self._version += 1
        if result.accepted and not isinstance(command, RUN_STATE_COMMANDS) \
                and not self.running:
            text.append(" — applies at the next scan (paused)", style=MUTED)
        self.message.say(text)
        self.poll(force=True)
        return result

    def _step_words(self) -> dict[str, str]:
        """The program's steps by their descriptions, for the answers that name them."""
        law = self.project.controls[self.facts.control]
        return {s.name: s.description for s in law.grafcet.steps if s.description} \
            if law.grafcet else {}

    def _situation_text(self, key: str) -> str:
        """A situation as the operator reads it in the alarm list (its one-line text), for
        the message line; its key where nothing shows it any more."""
        cell = self.link.last
        if cell is not None:
            for alarm in cell.alarms:
                if alarm.key == key:
                    return str(alarm.text)
            for alarm, _shelf in cell.shelved:
                if alarm.key == key:
                    return str(alarm.text)
            for explanation in cell.explanations:
                if explanation.key == key:
                    return str(explanation.what)
        return key

    def on_command_requested(self, message: CommandRequested) -> None:
        self.act(message.command)

    def _policy_command(self, key: str, policy_id: str) -> Command | None:
        """What choosing a policy sends, as the last explanation of `key` offered it."""
        cell = self.link.last
        if cell is None:
            return None
        explanation = next((e for e in cell.explanations if e.key == key), None)
        if explanation is None:
            alarm = next((a for a in cell.alarms if a.key == key), None)
            explanation = alarm.explanation if alarm else None
        policy = next((p for p in explanation.policies if p.id == policy_id), None) \
            if explanation else None
        return policy.command if policy else None

    def refuse(self, what: str, why: str) -> None:
        """A control that does not apply here; said, not silently ignored."""
        line = tag("NOT AVAILABLE", Level.ALARM)
        line.append(f" {what}: {why}")
        self.message.say(line)

    def _fault_text(self, injection: Injection) -> str:
        for device, code, description in self._faults():
            if code == injection.code and (injection.device in (None, device)):
                return description
        return injection.code

    def _faults(self) -> list[tuple[str, str, str]]:
        return list(self.facts.plant.faults)

    @property
    def simulated(self) -> bool:
        return not self.facts.plant.is_real

    # -- bindings ----------------------------------------------------------------------------
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if isinstance(self.screen, ModalScreen) and action in _ACTION_NAMES:
            return False  # a dialog is open: its own keys only
        if action in ("speed", "inject") and not self.simulated:
            return None  # shown dimmed: simulation only
        if action in ("manual_on", "manual_off", "manual_release"):
            if isinstance(self.screen, ModalScreen):
                return False
            return bool(self.frame and self.frame.manual_keys)  # else hidden (on_key says)
        return True

    async def on_event(self, event: events.Event) -> None:
        """A key typed before the dialog on top was painted is not the dialog's: dropped
        (a stray enter or y meant for the screen below must not answer it)."""
        if self.idle_timer is not None and self.idle_state != "locked" and isinstance(
                event, (events.Key, events.MouseDown, events.MouseScrollDown,
                        events.MouseScrollUp)):
            self._touched()
        if isinstance(event, events.Key) and not event.is_forwarded and \
                isinstance(self.screen, ModalScreen):
            from hmi.ui.dialogs import Dialog
            if isinstance(self.screen, Dialog) and not self.screen.takes(event):
                return
        await super().on_event(event)

    # -- the idle lock (hmi.access.sessions.IdleTimer) ----------------------------------------
    def _touched(self) -> None:
        assert self.idle_timer is not None
        self.idle_timer.touch()
        if self.idle_state == "warning":
            self.idle_state = "active"
            self.message.say(Text("still here: this screen stays signed in", style=MUTED))

    def check_idle_lock(self) -> None:
        """Once a second (live): the warning `idle-warning` before the lock, then the lock
        (the screen covered until the password is typed again; the runtime refuses this
        screen's commands meanwhile and journals both)."""
        idle = self.idle_timer
        if idle is None or self.idle_state == "locked":
            return
        state = idle.state()
        if state == "warning" and self.idle_state == "active":
            self.idle_state = "warning"
            left = max(1, round(idle.left()))
            line = tag("LOCKS SOON", Level.ATTENTION)
            line.append(f" nobody has touched this screen: it locks in {left} s; "
                        "press any key to stay signed in")
            self.message.say(line)
            self.notify(f"This screen locks in {left} s: press any key to stay signed in.",
                        title="Idle", severity="warning", timeout=min(left, 60))
        elif state == "locked":
            self._lock()

    def _lock(self) -> None:
        from hmi.ui.dialogs import LockScreen
        assert self.idle_timer is not None
        self.idle_state = "locked"
        result = self.link.lock()
        who = self.link.identity
        idle = format_duration(round(self.idle_timer.lock_after_s * 1e6))
        self.push_screen(LockScreen(f"{who.user} ({who.role})", idle, self._unlock))
        line = tag("LOCKED", Level.ATTENTION)
        line.append(f" left untouched for {idle}: sign in again to send anything")
        self.message.say(line if result.accepted else result_text("lock", result))

    def _unlock(self, password: str) -> CommandResult:
        result = self.link.unlock(password)
        if result.accepted:
            assert self.idle_timer is not None
            self.idle_timer.touch()
            self.idle_state = "active"
            self.message.say(Text("unlocked: signed in again", style=MUTED))
        return result

    def on_key(self, event: events.Key) -> None:
        """1 / 0 / x outside manual mode, b without push buttons: said, not silently
        ignored."""
        if isinstance(self.screen, ModalScreen):
            return
        if event.key in MANUAL_KEYS and not (self.frame and self.frame.manual_keys):
            event.stop()
            self.refuse("manual request", "not in manual mode (m enters it)")
        elif event.key == "b" and not self.free_inputs:
            event.stop()
            self.refuse("push button", "this project has no push button the operator "
                        "presses (b presses the highlighted one in a project that has)")

    def action_manual_on(self) -> None:
        self._manual_key(True)

    def action_manual_off(self) -> None:
        self._manual_key(False)

    def action_manual_release(self) -> None:
        self._manual_key(None)

    def _manual_key(self, value: bool | None) -> None:
        """A manual key pressed with the focus outside the I/O table: the table's
        highlighted output is the one requested."""
        name = self.query_one(IOPanel).selected
        if name is None:
            self.refuse("manual request", "no row highlighted in the I/O table")
            return
        self.action_manual_request(name, value)

    async def action_quit(self) -> None:
        """Quitting ends control of the plant: asked, with what happens to the outputs. A
        screen of a runtime in another process asks whether the cell stops too, or runs on
        without it (only the screen in control may stop it)."""
        from hmi.ui.dialogs import ConfirmDialog
        if not self.link.scans_here and not self.in_control:
            self.push_screen(ConfirmDialog("Quit this screen?", self._leave_lines(), "Quit",
                                           dialog_id="quit-dialog"), self._quit_confirmed)
            return
        title, lines, level = self._quit_lines()
        if self.link.scans_here:
            self.push_screen(ConfirmDialog(title, lines, "Quit", level=level,
                                           dialog_id="quit-dialog"), self._quit_confirmed)
            return
        lines = [Text("y: stop the cell", style="bold"), *lines,
                 Text("g: leave it running", style="bold"), *self._leave_lines()]
        self.push_screen(ConfirmDialog("Quit: stop the cell, or leave it running?", lines,
                                       "Stop the cell", level=level,
                                       dialog_id="quit-dialog",
                                       alternative="Leave it running"), self._quit_confirmed)

    def _quit_confirmed(self, yes: bool | str | None) -> None:
        if yes == "alternative":
            self.stop_cell = False
            self.exit()
        elif yes:
            self.stop_cell = not self.link.scans_here and self.in_control
            self.exit()
        else:
            self.message.say(Text("cancelled: quit — the scan goes on", style=MUTED))

    def _leave_lines(self) -> list[Text | str]:
        """Leaving without stopping the cell: what goes on, and who is in control."""
        view = self.link.view()
        holder = view.control.holder if view and view.control else None
        lines: list[Text | str] = ["The cell keeps running without this screen: its scan, "
                                   "the safety filter, the alarms and the journal go on."]
        if holder is None or holder.id == self.link.client:
            lines.append("Nobody is in control until a screen takes it (plchmi attach "
                         "shows the cell again).")
        else:
            lines.append(f"{holder} stays in control.")
        return lines

    @property
    def in_control(self) -> bool:
        """This screen is the one in control (the only one, for a session in this process)."""
        if self.link.client is None:
            return True
        view = self.link.view()
        holder = view.control.holder if view and view.control else None
        return holder is not None and holder.id == self.link.client

    def _quit_lines(self) -> tuple[str, list[Text | str], Level]:
        last = self.link.last
        snap = last.snapshot if last is not None else None
        lines: list[Text | str] = [
            "The scan stops: the control program and the safety filter no longer run."]
        level = Level.ATTENTION
        if self.simulated:
            lines.append("The simulated plant stops with it; no real output is driven.")
        else:
            level = Level.ALARM
            where = self.facts.plant.description
            safe = self.facts.safe_text()
            lines += [tag(f"Real plant ({where}): control ends.", Level.ALARM),
                      f"Every output is written to its safe value ({safe}), then the "
                      "connection is closed;",
                      "if the plant cannot be reached, its own communication watchdog "
                      "decides what the outputs do."]
        if snap is not None and snap.mode == "manual":
            forces = ", ".join(f"{n}={int(v)}" for n, v in snap.manual) or "none"
            lines.append(tag(f"Manual mode: the requests ({forces}) end with the scan.",
                             Level.ATTENTION))
        return "Quit plchmi?", lines, level

    def action_toggle_run(self) -> None:
        self.send(Pause() if self.running else Resume())

    def action_step(self) -> None:
        self.send(StepScans(1))

    def action_step_n(self) -> None:
        from hmi.ui.dialogs import StepDialog
        def done(count: int | None) -> None:
            if count:
                self.send(StepScans(count))
        self.push_screen(StepDialog(), done)

    def action_speed(self, factor: float | str | None = "next") -> None:
        if not self.simulated:
            self.refuse("run speed", "a real plant runs in real time only")
            return
        if factor == "next":
            view = self.link.view()
            current = view.run.speed if view is not None else 1.0
            index = SPEEDS.index(current) if current in SPEEDS else -1
            factor = SPEEDS[(index + 1) % len(SPEEDS)]
        assert not isinstance(factor, str)
        self.send(SetSpeed(factor))

    def action_manual(self) -> None:
        from hmi.ui.dialogs import ConfirmDialog
        last = self.link.last
        if last is None:
            return
        snap = last.snapshot
        if snap.mode == "recovery" or self._mode_commanded == "recovery":
            self.leave_recovery()
            return
        manual_now = self.frame.manual_keys if self.frame else snap.mode == "manual"
        if manual_now:
            requested = ", ".join(f"{n}={int(v)}" for n, v in snap.manual) or "none"
            lines = [f"Every manual request is released (now: {requested}).",
                     *self._leave_manual_lines(snap),
                     f"The safety filter keeps its policy ({snap.policy})."]
            self.push_screen(ConfirmDialog("Leave manual mode?", lines, "Leave manual",
                                           dialog_id="manual-dialog"),
                             partial(self._confirmed, SetMode(False)))
        else:
            self.push_screen(ConfirmDialog("Enter manual mode?", self._manual_lines(snap),
                                           "Enter manual",
                                           dialog_id="manual-dialog"),
                             partial(self._confirmed, SetMode(True)))

    def _manual_lines(self, snap: Snapshot) -> list[Text | str]:
        law = self.project.controls[self.facts.control]
        return [("The control program stops driving the outputs: they follow your "
                 "requests, and an output you have not requested is 0."),
                *manual.enter_lines(self.project, law, snap, self.engineering),
                f"Every request still goes through the safety filter ({snap.policy}).",
                "Select an output in the I/O table: 1 on, 0 off, x release."]

    def _leave_manual_lines(self, snap: Snapshot) -> list[Text | str]:
        law = self.project.controls[self.facts.control]
        return list(manual.leave_lines(self.project, law, snap, self.engineering))

    def action_manual_request(self, name: str, value: bool | None) -> None:
        self.act(ManualOutput(name, value))

    def action_reset(self, asked: Asked | None = None) -> None:
        """The fault reset dialog: what the reset would do as of the last scan; y carries it
        out only if it still does that (`asked`: the dialog the operator confirmed before,
        when asked again; see :meth:`_reset_if_unchanged`)."""
        from hmi.ui.dialogs import ConfirmDialog
        cell = self.link.last
        if cell is None:
            return
        shown = reset_preview(cell.snapshot, cell.alarms)
        recovery = next((line.recovery for line in shown if line.recovery), "")

        def answered(answer: bool | str | None) -> None:
            if answer == "alternative":
                self.start_recovery(recovery)
            elif answer:
                self._reset_if_unchanged(FaultReset(), shown, cell.snapshot, self.action_reset)
            else:
                self._confirmed(FaultReset(), False)
        self.push_screen(ConfirmDialog("Fault reset?",
                                       reset_lines(cell, asked, self.engineering), "Reset",
                                       dialog_id="reset-dialog",
                                       alternative="Start recovery" if recovery else None),
                         answered)

    def _reset_if_unchanged(self, command: Command, shown: list[ResetLine], seen: Snapshot,
                            ask_again: Callable[[Asked], None]
                            ) -> CommandResult | None:
        """A fault reset confirmed on the preview `shown` (as of `seen`): carried out only if
        the reset still does what that preview said, checked under the session's lock so no
        scan comes between the check and the reset. Otherwise nothing is done, the journal
        says so (Session.decline), and the operator is asked again (`ask_again`) with what
        changed first; None then."""
        answer = self.link.command(command, ResetGuard(tuple(shown), seen.scan))
        if not answer.declined:
            return self._sent(command, answer.result, shown)
        self._sent(command, answer.result)
        # (once the dialog answered is gone: the new one takes its place and its id)
        self.call_later(ask_again, Asked(tuple(shown), seen.scan, seen.time_us))
        return None

    # -- shelving and comments (hmi.explain.alarms) --------------------------------------------
    def shelve(self, key: str | None = None) -> None:
        """Shelve an alarm (the selected one): for how long, or once until it clears."""
        from hmi.ui.dialogs import ChoiceDialog
        alarm = self._listed_alarm(key, "shelve")
        if alarm is None:
            return
        if alarm.latched and alarm.active:  # refused before a duration is asked for
            self.refuse("shelve", "latched: a fault reset clears it once its cause is gone")
            return
        options = [("once", Text("once: until its condition clears")),
                   *((str(us), Text(f"for {label}")) for us, label in SHELVE_TIMES)]

        def chosen(answer: str | None) -> None:
            if answer is not None:
                self.act(Shelve(alarm.key, None if answer == "once" else int(answer)))
        self.push_screen(ChoiceDialog(f"Shelve: {alarm.text}", options, "once",
                                      dialog_id="shelve-dialog",
                                      note="Hidden from the list, journalled meanwhile, back "
                                           "by itself; a latched safety alarm cannot be "
                                           "shelved."), chosen)

    def _listed_alarm(self, key: str | None, what: str) -> Alarm | None:
        """The listed alarm `key` (default: the selected one), or None, said."""
        key = key or self.alarm_list.selected
        cell = self.link.last
        alarm = next((a for a in cell.alarms if a.key == key), None) if cell and key else None
        if alarm is None:
            self.refuse(what, "no alarm selected")
        return alarm

    def comment(self, key: str | None = None) -> None:
        from hmi.ui.dialogs import TextDialog
        alarm = self._listed_alarm(key, "comment")
        if alarm is None:
            return

        def written(text: str | None) -> None:
            if text:
                self.send(CommentAlarm(alarm.key, text))
        self.push_screen(TextDialog(f"Comment: {alarm.text}",
                                    "Your note on this alarm (journalled with your action):",
                                    dialog_id="comment-dialog"), written)

    # -- recovery (hmi.project.recovery) -------------------------------------------------------
    def start_recovery(self, name: str) -> None:
        """Confirm, then enter recovery mode running procedure `name`."""
        from hmi.ui.dialogs import ConfirmDialog
        spec = next((p for p in recoveries_of(self.project) if p.name == name), None)
        if spec is None:
            self.refuse("recovery", f"no recovery procedure {name!r}")
            return
        self.push_screen(ConfirmDialog(f"Start recovery: {spec.description}?",
                                       recovery_lines(self.project, spec, self.engineering),
                                       "Start recovery",
                                       level=Level.ALARM, dialog_id="recovery-dialog"),
                         partial(self._confirmed, StartRecovery(name)))

    def leave_recovery(self) -> None:
        from hmi.ui.dialogs import ConfirmDialog
        last = self.link.last
        snap = last.snapshot if last is not None else None
        state = snap.recovery if snap else None
        reached = {"done": "The recovery is done.", "failed": "The recovery failed."}.get(
            state.status if state else "", "The recovery is stopped where it is.")
        lines: list[Text | str] = [
                 reached,
                 "Automatic mode: the control program starts again from its initial steps,",
                 "through the safety filter "
                 f"({snap.policy if snap else 'unchanged'})."]
        if snap is not None and any(d.faulty for d in snap.diagnosers):
            lines.append(tag("A diagnosis is still latched: r (fault reset) first, or the "
                             "device stays masked.", Level.ATTENTION))
        self.push_screen(ConfirmDialog("Leave recovery mode?", lines, "Leave recovery",
                                       dialog_id="recovery-dialog"),
                         partial(self._confirmed, EndRecovery()))

    def action_ack(self) -> None:
        key = self.alarm_list.selected
        if key is None:
            self.refuse("acknowledge", "no alarm in the list")
            return
        self.send(Acknowledge(key))

    def action_ack_all(self) -> None:
        self.send(Acknowledge(None))

    def action_explain(self) -> None:
        panel = self.explanation_panel
        if panel.key is None:
            self.refuse("explanation", "no alarm selected, nothing to explain")
            return
        panel.open_next_level()

    def action_policy(self, policy: str | None = None) -> None:
        from hmi.ui.dialogs import ChoiceDialog
        last = self.link.last
        current = last.snapshot.policy if last is not None else ""
        if policy is not None:
            self._confirm_policy(current, policy)
            return
        # the current one marked before its help, which may be cut at 80 columns
        options = [(p, Text(f"{'●' if p == current else ' '} {p:<8}"
                            f"{' now ' if p == current else '     '} {POLICY_HELP[p]}",
                            no_wrap=True, overflow="ellipsis"))
                   for p in POLICIES]

        def chosen(policy: str | None) -> None:
            if policy is not None:
                self._confirm_policy(current, policy)
        self.push_screen(ChoiceDialog("Safety filter policy", options, current,
                                      dialog_id="policy-dialog"), chosen)

    def _confirm_policy(self, current: str, policy: str) -> None:
        from hmi.ui.dialogs import ConfirmDialog
        if policy == current:  # nothing to confirm: nothing would change
            self.message.say(Text(f"filter policy: already {policy} — nothing changed",
                                  style=MUTED))
            return
        level = Level.ALARM if policy == "monitor" else Level.ATTENTION
        lines: list[Text | str] = [f"{current} → {policy}: {POLICY_HELP[policy]}."]
        if policy == "monitor":
            lines.append(tag("Unsafe orders will reach the plant; the filter only reports.",
                             Level.ALARM))
        self.push_screen(ConfirmDialog(f"Switch the filter policy to {policy}?", lines,
                                       f"Switch to {policy}", level=level,
                                       dialog_id="policy-confirm"),
                         partial(self._confirmed, SetPolicy(policy)))

    def _confirmed(self, command: Command, yes: bool | None) -> None:
        if yes:
            self.act(command)
        else:
            self.message.say(Text(f"cancelled: {describe(command)}", style=MUTED))

    def action_inject(self) -> None:
        from hmi.ui.fault_dialog import FaultDialog
        if not self.simulated:
            self.refuse("fault injection", "only a simulated plant can be given faults")
            return
        devices = {device for device, _, _ in self._faults()}

        def chosen(injection: Injection | None) -> None:
            if injection is not None:
                self._inject(injection)
        self.push_screen(FaultDialog(self._faults(), self._now, len(devices) <= 1,
                                     self.engineering), chosen)

    def action_inject_now(self, device: str, code: str) -> None:
        devices = {d for d, _, _ in self._faults()}
        self._inject(Injection(code, self._now(),
                               None if len(devices) <= 1 else device))

    def _inject(self, injection: Injection) -> None:
        """Send an injection, unless the same fault is already scheduled or in effect (a
        simulated fault is never repaired: a second one would change nothing)."""
        for old in self._injected:
            same = old.injection
            if (same.code, same.device) != (injection.code, injection.device):
                continue
            if same.duration_us is None or same.at_us + same.duration_us > injection.at_us:
                when = "in effect" if same.at_us <= self._now() \
                    else "scheduled"
                self.refuse(f"fault injection {injection.code}",
                            f"already {when} since {seconds(same.at_us)} s ({old.description})"
                            if when == "in effect" else
                            f"already scheduled at {seconds(same.at_us)} s")
                return
        self.send(InjectFault(injection))

    def _now(self) -> int:
        """The cell's time as of the newest snapshot (a fault injected now, in N s)."""
        last = self.link.last
        return last.snapshot.time_us if last is not None else 0

    def action_button(self, name: str, value: bool) -> None:
        self.send(SetInput(name, value))

    def action_signals(self) -> None:
        from hmi.ui.signal_dialog import SignalDialog
        chrono = self.chronogram
        descriptions = {n: self.project.describe(n) for n in self.facts.layout.names}
        law = self.project.controls[self.facts.control]
        if law.grafcet:
            descriptions.update({s.name: s.description for s in law.grafcet.steps})

        def chosen(signals: tuple[str, ...] | None) -> None:
            if signals is not None:
                self.set_signals(signals)
        self.push_screen(SignalDialog(self.history.signals, chrono.signals, descriptions),
                         chosen)

    def _history_now(self, snap: Snapshot | None = None) -> int:
        """The newest scan on the history's time axis (Session.wall_us)."""
        if snap is None:
            last = self.link.last
            snap = last.snapshot if last is not None else None
        epoch = self.facts.epoch_us
        if epoch is None:
            import time
            return time.time_ns() // 1000
        return epoch + (snap.time_us if snap is not None else 0)

    def action_trends(self) -> None:
        self.open_trends()

    def open_trends(self, signals: tuple[str, ...] | None = None,
                    whole: bool = False) -> None:
        """The trend screen (hmi.ui.trend_screen) on the chronogram's signals (or
        `signals`); `whole`: zoomed out to all of the history."""
        from hmi.ui.trend_screen import TrendScreen
        history = self.facts.history
        if not history:
            self.refuse("trends", "no history is kept for this session (it was started "
                        "with --historian off)")
            return
        chosen = signals if signals is not None else self.chronogram.signals
        screen = TrendScreen(history, self.project.name, chosen, self._history_now(),
                             zone=self.trend_zone, whole=whole)
        self.trends = screen

        def closed(_: object) -> None:
            if self.trends is screen:
                self.trends = None
        self.push_screen(screen, closed)

    def set_signals(self, signals: tuple[str, ...]) -> None:
        self.chronogram.signals = signals
        self.chronogram.refresh(layout=True)
        self.message.say(f"{OK_SYMBOL} chronogram: " + (", ".join(signals) or "no signals"))

    def toggle_signal(self, name: str) -> None:
        current = self.chronogram.signals
        if name in current:
            self.set_signals(tuple(s for s in current if s != name))
        else:
            order = [s.name for s in self.history.signals]
            self.set_signals(tuple(sorted((*current, name), key=order.index)))

    def get_system_commands(self, screen: Screen[Any]) -> Iterable[SystemCommand]:
        """Textual's entries, its Screenshot replaced by one that says where it saved (or
        why it could not) and keeps the words apart in every SVG viewer."""
        for command in super().get_system_commands(screen):
            if command.title != "Screenshot":
                yield command
        yield SystemCommand("Screenshot", "Save an SVG picture of the screen in the folder "
                            "the HMI was started in", self.action_svg_screenshot)

    def action_svg_screenshot(self) -> None:
        from hmi.ui.screenshot import save_svg, screenshot_name
        name = screenshot_name(self.project.name)
        try:
            path = save_svg(self.export_screenshot(), Path.cwd(), name)
        except OSError as exc:  # (the folder gone, read-only, full)
            self.refuse("screenshot", f"{name} not written: {exc.strerror or exc}"
                        + (f" ({exc.filename})" if exc.filename else ""))
            return
        self.message.say(Text(f"{OK_SYMBOL} screenshot: {path}"))

    def action_engineering(self) -> None:
        """The engineering view on or off: one key, shown in the status bar, journalled."""
        self.send(SetView(not self.engineering))

    def action_window(self, window_us: int | None = None) -> None:
        chrono = self.chronogram
        if window_us is None:
            index = WINDOWS_US.index(chrono.window_us) if chrono.window_us in WINDOWS_US \
                else -1
            window_us = WINDOWS_US[(index + 1) % len(WINDOWS_US)]
        chrono.window_us = window_us
        chrono.refresh()
        self.message.say(f"{OK_SYMBOL} chronogram: last {window_us // 1_000_000} s")

    # -- the command palette -----------------------------------------------------------------
    def palette_entries(self) -> list[PaletteEntry]:
        """Every control, as palette commands; the ones that do not apply now are left out."""
        from hmi.ui.palette import PaletteEntry
        entries: list[PaletteEntry] = []
        for a in ACTIONS:
            if a.action in ("speed", "inject") and not self.simulated:
                continue
            entries.append(PaletteEntry(f"{a.title}  [{a.key_display or a.key}]", a.help,
                                        getattr(self, f"action_{a.action}"), a.action))
        cell = self.link.last
        if self.simulated:
            for factor, word in ((1.0, "real time"), (10.0, "×10"),
                                 (None, "as fast as possible")):
                entries.append(PaletteEntry(f"Run speed: {word}", "Simulated plant only",
                                            partial(self.action_speed, factor)))
        for count in (10, 100):
            entries.append(PaletteEntry(f"Step {count} scans", "Run them, then stay paused",
                                        partial(self.send, StepScans(count))))
        if cell is not None and self.frame is not None and self.frame.manual_keys:
            for name in cell.snapshot.layout.outputs:
                for value, word, key in ((True, "on", "1"), (False, "off", "0"),
                                         (None, "release", "x")):
                    entries.append(PaletteEntry(
                        f"Manual: {name} {word}  [{key}]",
                        f"Request {self.project.describe(name)} {word} (filtered)",
                        partial(self.action_manual_request, name, value),
                        f"manual_{'on' if value else 'off' if value is False else 'release'}"))
        for policy in POLICIES:
            entries.append(PaletteEntry(f"Filter policy: {policy}…", POLICY_HELP[policy],
                                        partial(self.action_policy, policy)))
        if cell is not None:
            entries += self._situation_entries(cell)
        if self.simulated:
            several = len({device for device, _, _ in self._faults()}) > 1
            for device, code, description in self._faults():
                entries.append(PaletteEntry(
                    f"SIMULATION: inject {device}.{code} now" if self.engineering else
                    f"SIMULATION: inject now: {fault_words(device, description, several)}",
                    description, partial(self.action_inject_now, device, code)))
            entries.append(PaletteEntry(
                "SIMULATION: repair the faulty devices",
                "The technician's repair: injected faults removed; then a fault reset, "
                "which says first what it resets and what stays",
                partial(self.send, RepairFaults())))
            for name in self.free_inputs:
                for value, word in ((True, "press"), (False, "release")):
                    entries.append(PaletteEntry(
                        f"SIMULATION: {word} button {name}  [b]",
                        self.project.describe(name),
                        partial(self.action_button, name, value), "button"))
        shown = set(self.chronogram.signals)
        for signal in self.history.signals:
            verb = "hide" if signal.name in shown else "show"
            entries.append(PaletteEntry(f"Chronogram: {verb} {signal.name}",
                                        self.project.describe(signal.name.split(".")[0]),
                                        partial(self.toggle_signal, signal.name)))
        for window in WINDOWS_US:
            entries.append(PaletteEntry(f"Chronogram: last {window // 1_000_000} s",
                                        "Time window of the timing diagram",
                                        partial(self.action_window, window)))
        entries += self._control_entries()
        if self.facts.history:
            from hmi.history.catalogue import catalogue
            found = catalogue(self.project, self.facts.layout)
            for device in found.devices():
                entries.append(PaletteEntry(
                    f"Trends: maintenance of {device}",
                    "Its travel times and operations over the whole history",
                    partial(self.open_trends, found.maintenance(device), True)))
        if self.served is not None or (self.frame is not None
                                       and self.frame.gateway is not None):
            entries.append(PaletteEntry(
                "OPC UA server: endpoint, clients, security",
                "What the SCADA sees of this cell: where it is served, who is connected",
                self.show_serving))
        return entries

    def show_serving(self) -> None:
        """The OPC UA server's page: endpoint, clients and their security (palette)."""
        from hmi.ui.dialogs import InfoDialog
        if self.served is not None:
            self.push_screen(InfoDialog("OPC UA server", serving_lines(self.served.status()),
                                        dialog_id="opcua-dialog"))
        elif self.frame is not None and self.frame.gateway is not None:
            self.push_screen(InfoDialog("OPC UA server", gateway_lines(self.frame.gateway),
                                        dialog_id="opcua-dialog"))


    def _situation_entries(self, cell: CellView) -> list[PaletteEntry]:
        """Per alarm and situation: acknowledge, explain, its policies; stopped devices."""
        from hmi.ui.palette import PaletteEntry
        entries: list[PaletteEntry] = []
        for alarm in cell.alarms:
            if alarm.state != "active-acknowledged":
                entries.append(PaletteEntry(f"Alarms: acknowledge {alarm.text}",
                                            f"{alarm.state}, P{alarm.priority}",
                                            partial(self.send, Acknowledge(alarm.key))))
        explained = {e.key: e for e in cell.explanations}
        for alarm in cell.alarms:
            if alarm.key not in explained and alarm.explanation is not None:
                explained[alarm.key] = alarm.explanation
        for key, explanation in explained.items():
            entries.append(PaletteEntry(f"Explain: {explanation.what}",
                                        f"{explanation.severity} · {key}",
                                        partial(self.explain, key)))
        panel = self.explanation_panel
        if panel.key is not None and panel.explanation is not None:
            for policy in panel.explanation.policies:
                mark = " (recommended)" if policy.recommended else ""
                entries.append(PaletteEntry(
                    f"Policy: {policy.label}{mark} — {panel.explanation.device}"
                    + ("…" if policy.command is not None else ""),
                    policy.effect, partial(self.choose_policy, panel.key, policy)))
        if cell.snapshot.mode == "recovery":
            entries.append(PaletteEntry("Recovery: leave…", "Automatic mode again; the "
                                        "program starts from its initial steps",
                                        self.leave_recovery))
        else:
            needed = {n[0] for n in cell.snapshot.recovery.needed}
            for spec in recoveries_of(self.project):
                mark = " (needed now)" if spec.name in needed else ""
                entries.append(PaletteEntry(
                    f"Recovery: start — {spec.description}{mark}…",
                    f"{spec.device}: recovery mode, filtered by its own constraints",
                    partial(self.start_recovery, spec.name)))
        for alarm in cell.alarms:
            if not (alarm.latched and alarm.active):  # what would be refused is not offered
                entries.append(PaletteEntry(f"Alarms: shelve… {alarm.text}",
                                            "Hide it from the list for a while or until it "
                                            "clears (journalled meanwhile)",
                                            partial(self.shelve, alarm.key)))
            entries.append(PaletteEntry(f"Alarms: comment on {alarm.text}…",
                                        "A note on this alarm, in the journal",
                                        partial(self.comment, alarm.key)))
        for alarm, shelf in cell.shelved:
            entries.append(PaletteEntry(f"Alarms: unshelve {alarm.text}",
                                        f"shelved {shelf.describe()}",
                                        partial(self.send, Unshelve(alarm.key))))
        for device in cell.snapshot.stopped_devices:
            entries.append(PaletteEntry(f"Release device {device}",
                                        "Its outputs follow the program (and the filter) again",
                                        partial(self.send, ReleaseDevice(device))))
        return entries


_ACTION_NAMES = {a.action for a in ACTIONS}


@dataclass(frozen=True)
class AppEnd:
    """How the HMI ended: exit status 0 when the operator quit, else 1 with the reason."""

    status: int
    reason: str | None = None  # None: ended as asked
    # ended as asked, but UI errors were contained meanwhile: the journal's stop says so
    # instead of "ended normally"
    note: str | None = None


def run_app(target: Engine | Session, clock: Callable[[], int] | None = None,
            injected: tuple[Injection, ...] = (),
            on_fault: Callable[[UIFault], None] | None = None, bell: bool = False,
            served: Served | None = None,
            on_first_frame: Callable[[], None] | None = None) -> AppEnd:
    """Run the HMI live on an engine, or on a session others listen to (the journal).

    A real plant passes a wall clock to stamp its scans (see hmi.session.live.WallClock);
    `injected` are the faults the command line scheduled in a simulated plant; `on_fault`
    is told of every UI error (the journal); `served` is the cell's OPC UA server, whose
    state the screen shows; `on_first_frame` is called once the first frame is shown."""
    session = target if isinstance(target, Session) else Session(target, clock=clock)
    app = PlcHmiApp(session, injected=injected, bell=bell, served=served)
    if on_fault is not None:
        app.containment.listeners.append(on_fault)
    if on_first_frame is not None:
        app.first_frame_listeners.append(on_first_frame)
    app.run()
    return app_end(app)


def app_end(app: PlcHmiApp) -> AppEnd:
    """Why the app stopped: a fatal error (Textual's last resort, the scan thread), any
    non-zero return code, or the operator's quit."""
    fatal = app.containment.fatal
    if fatal is not None:
        return AppEnd(1, f"{fatal.what}: {fatal.error} (details in {fatal.report})")
    if app.return_code:
        return AppEnd(1, f"the HMI stopped with return code {app.return_code}")
    contained = app.containment
    if contained.total:
        first = next(iter(contained.faults.values()))
        return AppEnd(0, note=f"after {contained.total} contained UI error"
                      f"{'s' if contained.total > 1 else ''} (first: {first.what}: "
                      f"{first.error}; see the ui-error entries)")
    return AppEnd(0)
