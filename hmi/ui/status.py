"""The status bar and the banners under it: the two things that must survive any screen size.

The status bar is one line. When the terminal is narrow it uses short forms, then drops its
least important fields first (measured scan time, plant details; the project name among
the last) and never the mode, the filter policy, the run state, the count of the most urgent
unacknowledged alarms (``✗ 3 P1 unack``) nor the late-scan flag — unless these alone are
still too wide. Then the words on how this screen is used give way to the cell's state
(the engineering view, then who is in control), and, last, what follows the alarm count, so
that the count is whole: a new P1 is never out of sight. The banner
strip appears only while something abnormal is in effect: manual mode
(MANUAL / FORCES ACTIVE), recovery mode (RECOVERY, with its step), a device the operator
stopped, outputs latched in the safe state, and, for the rest of the session, an error of the
UI that was contained (what failed, and the file with the details: hmi.ui.containment). The
mode and the filter policy never drop from the status bar.
"""

from __future__ import annotations

from dataclasses import dataclass

from rich.text import Text

from hmi.engine.recovery import RecoveryState
from hmi.explain.plain import latch_words
from hmi.explain.reset import reset_preview
from hmi.timefmt import seconds
from hmi.ui.alarm_list import urgent_count
from hmi.ui.frame import Frame
from hmi.ui.panel import TextPanel
from hmi.ui.presence import control_field, lost_banner, lost_field, lost_fields
from hmi.ui.serving import gateway_banner, gateway_field, serving_banner, serving_field
from hmi.ui.style import MUTED, Level, banner, tag

SEPARATOR = " │ "


@dataclass(frozen=True)
class Field:
    text: Text
    priority: int  # 0 is kept longest
    # among the fields kept longest, which go first when they alone are too wide (0: never)
    gives_way: int = 0
    alarm_count: bool = False  # the count of the most urgent unacknowledged alarms


def speed_text(speed: float | None) -> str:
    return "max" if speed is None else f"×{speed:g}"


def status_fields(frame: Frame, wide: bool, compact: bool = False) -> list[Field]:
    """The status bar's fields; `compact` uses the short forms (80 columns)."""
    snap = frame.snapshot
    plant = snap.plant
    if frame.lost:  # nothing is live: said first, and only what was last known
        return [Field(*f) for f in lost_fields(frame)]
    fields: list[Field] = [Field(Text(frame.project, style="bold"), 2)]
    if (gone := lost_field(frame)) is not None:  # first: what follows may be stale
        fields.insert(0, Field(*gone))
    if plant.kind == "sim":
        fields.append(Field(tag("SIM", Level.SIMULATION), 2))
    else:
        where = plant.description if wide else plant.kind
        if plant.connected:
            fields.append(Field(Text(f"{where} ● connected"), 3))
        else:
            fields.append(Field(tag(f"{where} DISCONNECTED", Level.ALARM), 0))
    if frame.serving is not None:
        fields.append(Field(*serving_field(frame.serving)))
    elif frame.gateway is not None:
        fields.append(Field(*gateway_field(frame.gateway)))
    # Who is in control and the engineering view are kept as long as the cell's state fits
    # beside them; then they give way to it, the view first (its panels show it anyway),
    # then control (the message line says when it changes, and every refused command why)
    if (control := control_field(frame)) is not None:
        fields.append(Field(*control, gives_way=1))
    if frame.engineering:  # the screen then names the model's internals
        fields.append(Field(tag("ENG" if compact else "ENG VIEW", Level.ATTENTION), 0,
                            gives_way=2))
    if snap.mode == "manual":
        fields.append(Field(tag("MANUAL", Level.ATTENTION), 0))
    elif snap.mode == "recovery":
        fields.append(Field(tag("RECOVERY", Level.ATTENTION), 0))
    else:
        fields.append(Field(Text("AUTO"), 0))
    # the mode and the filter policy are never dropped (a soak invariant): what protects the
    # cell must always be on screen
    filter_word = "" if compact else "filter "
    if snap.policy == "monitor":
        fields.append(Field(tag(f"{filter_word}monitor", Level.ATTENTION), 0))
    else:
        fields.append(Field(Text(f"{filter_word}{snap.policy}"), 0))
    # The most urgent unacknowledged alarms, counted: never dropped nor cut, whatever the
    # list shows (a soak invariant)
    alarms = frame.cell.alarms
    urgent = urgent_count(alarms)
    if urgent:
        priority = alarms[0].priority
        word = "unack" if compact else "unacknowledged"
        fields.append(Field(tag(f"{urgent} P{priority} {word}",
                                Level.ALARM if priority == 1 else Level.ATTENTION), 0,
                            alarm_count=True))
    report = snap.filter_report
    if report is not None and report.violations:
        count = len(report.violations)
        unsafe = report.unsafe_written or report.safe_state
        word = "violated" if compact else ("constraint violated" if count == 1
                                           else "constraints violated")
        fields.append(Field(tag(f"{count} {word}", Level.ALARM if unsafe else Level.ATTENTION),
                            1))
    if snap.latched:
        fields.append(Field(tag("SAFE STATE", Level.ALARM), 0))
    if frame.cell.error:
        fields.append(Field(tag("INTERNAL ERROR", Level.ALARM), 0))
    if frame.run == "running":
        word = "run" if compact else "running"
        fields.append(Field(Text(f"▶ {word} {speed_text(frame.speed)}"), 0))
    else:
        fields.append(Field(tag(frame.run.upper(), Level.ATTENTION), 0))
    if frame.show_measured and frame.overruns:
        # a compact flag kept at every width: the cell ran behind time (the tooltip says more)
        fields.append(Field(tag(f"{frame.overruns} late" if compact
                                else late_text(frame.overruns), Level.ATTENTION), 0))
    fields.append(Field(Text(f"#{snap.scan}" if compact else f"scan {snap.scan}"), 1))
    fields.append(Field(Text(f"{seconds(snap.time_us)} s" if compact
                             else f"t {seconds(snap.time_us)} s"), 1))
    if frame.show_measured:
        unit = "µs" if compact else "µs/scan"
        fields.append(Field(Text(f"{frame.cell.scan_wall_us:.0f} {unit}", style=MUTED), 5))
    return fields


def late_text(overruns: int) -> str:
    return f"{overruns} scan{'s' if overruns != 1 else ''} late"


def late_help(overruns: int) -> str:
    """What the late-scan count means (the status bar's tooltip)."""
    return (f"{late_text(overruns)}: {'they' if overruns != 1 else 'it'} ended more than a "
            "whole scan period behind schedule (the machine was busy). The schedule starts "
            "again from then: no scan is run twice to catch up.")


def join(fields: list[Field]) -> Text:
    line = Text(" ", no_wrap=True, overflow="ellipsis")
    for i, f in enumerate(fields):
        if i:
            line.append(SEPARATOR, style=MUTED)
        line.append_text(f.text)
    return line


def fit(fields: list[Field], width: int) -> Text:
    """Join fields with separators, dropping the least important until the line fits.

    When only the fields kept longest are left and they are still too wide, those that give
    way go (the highest `gives_way` first, and back in if it fits once a later one went);
    then, if the alarm count would still be cut, the fields after it; what is left is
    cropped at the right edge."""
    kept = list(fields)

    def too_wide(upto: int) -> bool:
        return join(kept[:upto]).cell_len > width

    while too_wide(len(kept)) and len(kept) > 1:
        worst = max(range(len(kept)), key=lambda i: (kept[i].priority, i))
        if kept[worst].priority == 0:
            break
        kept.pop(worst)
    place = {id(f): i for i, f in enumerate(fields)}
    gone: list[Field] = []
    while too_wide(len(kept)) and any(f.gives_way for f in kept):
        gone.append(kept.pop(max(range(len(kept)), key=lambda i: kept[i].gives_way)))
    for field in reversed(gone[:-1]):  # one that went first may fit once a later one went
        back = sorted([*kept, field], key=lambda f: place[id(f)])
        if join(back).cell_len <= width:
            kept = back
    count = next((i for i, f in enumerate(kept) if f.alarm_count), None)
    # a cropped line ends in "…" at its last cell: the count is whole if it ends before
    while count is not None and len(kept) > count + 1 and too_wide(len(kept)) \
            and join(kept[:count + 1]).cell_len > width - 1:
        kept.pop()
    return join(kept)


class StatusBar(TextPanel):
    """Project, plant, mode, filter policy, run state, scan number, virtual time, scan time."""

    def __init__(self, *, id: str | None = None):
        super().__init__(id=id)
        self.frame: Frame | None = None

    def show(self, frame: Frame) -> None:
        self.frame = frame
        self._draw()

    def on_resize(self) -> None:
        self._draw()

    def _draw(self) -> None:
        if self.frame is None:
            self.show_text(Text("starting…"))
            return
        width = self.size.width or 80
        wide = width >= 120
        tooltip = late_help(self.frame.overruns) if self.frame.overruns and \
            self.frame.show_measured else None
        if self.tooltip != tooltip:
            self.tooltip = tooltip
        line = join(status_fields(self.frame, wide))
        if line.cell_len > width:  # short forms first, then drop the least important
            line = fit(status_fields(self.frame, wide, compact=True), width)
        self.show_text(line)


class BannerStrip(TextPanel):
    """Banners for states the operator must never forget: manual forces, safe-state latch."""

    def __init__(self, *, id: str | None = None):
        super().__init__(id=id)
        self.display = False

    def show(self, frame: Frame) -> None:
        lines = banner_lines(frame)
        if self.display != bool(lines):
            self.display = bool(lines)
        if lines:
            self.show_text(Text("\n").join(lines))


def recovery_banner(state: RecoveryState, reset_pending: bool = True) -> Text:
    """RECOVERY: what runs and how far it got, and the way out. Done, the next key follows
    what is left: a fault reset only while it has something to release (`reset_pending`),
    then leaving recovery."""
    if state.status == "running":
        line = banner("RECOVERY", Level.ATTENTION)
        line.append(f" {state.step_text} {state.step}/{state.steps} · "
                    f"{state.elapsed_us / 1e6:.1f}/{state.timeout_us / 1e6:.1f} s · "
                    f"{state.description} · m: leave")
    elif state.status == "done":
        line = banner("RECOVERY DONE", Level.ATTENTION)
        step = "r fault reset, then m leave recovery" if reset_pending else \
            "m leave recovery"
        line.append(f" next: {step} · {state.description}")
    else:
        line = banner("RECOVERY FAILED", Level.ALARM)
        line.append(f" {state.message} · m: leave recovery")
    return line


def banner_lines(frame: Frame) -> list[Text]:
    snap = frame.snapshot
    lines: list[Text] = []
    if (gone := lost_banner(frame)) is not None:
        lines.append(gone)
    if snap.mode == "manual":
        line = banner("MANUAL / FORCES ACTIVE", Level.ATTENTION)
        requests = dict(snap.manual)
        forced = " ".join(f"{name}={int(value)}" for name, value in requests.items())
        line.append(f" requests: {forced or 'none (all outputs 0)'}"
                    f" · filtered ({snap.policy}) · m: leave")
        lines.append(line)
    if snap.mode == "recovery":
        lines.append(recovery_banner(snap.recovery, snap.recovery.status == "done" and any(
            line.resets for line in reset_preview(snap, frame.cell.alarms))))
    if not snap.plant.connected:
        line = banner("PLANT DISCONNECTED", Level.ALARM)
        line.append(f" {snap.plant.description}: {snap.plant.message or 'no answer'}")
        lines.append(line)
    if snap.stopped_devices:
        stopped = ", ".join(snap.stopped_devices)
        line = banner("DEVICE STOPPED" if len(snap.stopped_devices) == 1
                      else "DEVICES STOPPED", Level.ATTENTION)
        line.append(f" {stopped}: outputs held safe by the operator"
                    " · ctrl+p: Release device")
        lines.append(line)
    if snap.latched:
        line = banner("OUTPUTS HELD IN SAFE STATE", Level.ALARM)
        line.append(" " + "; ".join(r.detail if frame.engineering else latch_words(r)
                                    for r in snap.latched)
                    + " · r: fault reset once the cause is gone")
        lines.append(line)
    if frame.serving is None and frame.gateway is not None \
            and (served := gateway_banner(frame.gateway)) is not None:
        lines.append(served)
    if frame.serving is not None and (served := serving_banner(frame.serving)) is not None:
        lines.append(served)
    fault = frame.ui_fault
    if fault is not None:
        line = banner("UI ERROR", Level.ALARM)
        count = f" ({frame.ui_faults} errors)" if frame.ui_faults > 1 else ""
        line.append(f"{count} {fault.what}: {fault.error} · the scan goes on · details: "
                    f"{fault.report}")
        lines.append(line)
    for line in lines:
        line.no_wrap = True
        line.overflow = "ellipsis"
    return lines
