"""The control program's state: GRAFCET steps (active ones marked, with their activity time)
and the timers with their elapsed time against the preset.

On a short screen (under 30 lines) shared with the monitors or diagnosers, only the active
steps are listed (the title says how many: ``2/6 active``).

No colour here: an active step is normal. It is marked by a filled dot and bold text; the
time a step has been active is what tells an engineer the sequence is stuck (a valve that
never reaches its end switch keeps its "Opening" step active for ever).

In manual mode the program waits (no step changes, its step times and memories hold, and it
resumes from these steps when manual mode is left): the first line says so, with the
attention symbol, as soon as manual mode is commanded (paused, before a scan shows it).

Under each active step, what it waits for (S7-GRAPH's criteria analysis, read from the
snapshot: Snapshot.waits): each transition leaving it, its receptivity and the current
values of what it reads, ``↳ waits for B and e — B 0, e 1``; a join's other steps still to
come, ``…, and X10 active``; ``✓ met`` once it holds (in manual mode: it goes on when the
program resumes). A join whose steps are all active is shown once, under the last of them.
A step past its supervision time (the program stuck there, an alarm) reads ``✗ stuck``, in
the alarm colour, instead of the arrow.

In recovery mode the procedure drives the outputs and the program waits, to start again from
its initial steps when recovery is left: the first line says so, and the steps it was in read
``‖ … (held)``, with no time running and nothing they wait for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from rich.style import Style
from rich.text import Text

from hmi.engine.criteria import Wait
from hmi.explain.plain import lower_first, without_notes
from hmi.ui.frame import Frame
from hmi.ui.panel import TextPanel, set_title
from hmi.ui.style import MUTED, OK_SYMBOL, STYLE, SYMBOL, Level, tag

BAR = 10
SHORT = 30  # below this height the panel may list the active steps only


@dataclass(frozen=True)
class StepInfo:
    name: str
    description: str


@dataclass(frozen=True)
class TimerInfo:
    name: str
    kind: str
    description: str


def _plain_timer(info: TimerInfo) -> str:
    """A timer in words: its description without its notes ('' without one)."""
    return lower_first(without_notes(info.description))


def _secs(us: int) -> str:
    return f"{us / 1_000_000:6.2f} s"


def timer_time(elapsed_us: int, preset_us: int) -> str:
    """'0.03/0.2 s': the time run and the preset in one unit (it read '0.03/200ms')."""
    return f"{elapsed_us / 1e6:4.2f}/{preset_us / 1e6:g} s"


def timer_bar(elapsed_us: int, preset_us: int, width: int = BAR) -> str:
    filled = 0 if preset_us <= 0 else min(width, elapsed_us * width // preset_us)
    return "▕" + "█" * filled + "·" * (width - filled) + "▏"


class GrafcetPanel(TextPanel):
    def __init__(self, control: str, steps: list[StepInfo], timers: list[TimerInfo], *,
                 words: Callable[[Wait], str] | None = None, id: str | None = None):
        super().__init__(id=id)
        # what a step waits for in the operator's words (hmi.explain.sequence.wait_words);
        # the engineering view prints the receptivity and its variables
        self.words = words
        self.control = control
        self.steps = steps
        self.timers = timers
        self.frame: Frame | None = None
        # the waits shown under each active step (TextPanel._shown is the text last shown)
        self._waits_shown: dict[str, list[Wait]] = {}

    def on_mount(self) -> None:
        self.border_title = f"Control · {self.control}"

    @property
    def compact(self) -> bool:
        """Active steps and running timers only: on a short screen, when panels share this
        column with it (monitors, diagnosers), so that theirs are not the rows lost."""
        if self.app.size.height >= SHORT or self.parent is None:
            return False
        return any(c.display for c in self.parent.children if c is not self)

    def show(self, frame: Frame) -> None:
        self.frame = frame
        self.show_text(self.render_frame(frame))

    def on_resize(self) -> None:
        if self.frame is not None:
            self.show_text(self.render_frame(self.frame))

    def _placed(self, waits: tuple[Wait, ...], active: set[str]) -> dict[str, list[Wait]]:
        """Each wait under the step it is shown under: its own, or for a join whose steps
        are all active, the last of them in the panel's order (shown once)."""
        order = {s.name: k for k, s in enumerate(self.steps)}
        placed: dict[str, list[Wait]] = {}
        seen: set[int] = set()
        for wait in waits:
            if wait.transition in seen:
                continue
            seen.add(wait.transition)
            sources = [wait.step] + [s for s in self._sources(wait) if s in active]
            under = max(sources, key=lambda s: order.get(s, -1))
            placed.setdefault(under, []).append(wait)
        return placed

    def _sources(self, wait: Wait) -> tuple[str, ...]:
        frame = self.frame
        grafcet = frame.snapshot.layout.grafcet if frame is not None else None
        if grafcet is None:
            return ()
        return next((t.sources for t in grafcet.transitions if t.number == wait.transition),
                    ())

    def _wait_line(self, text: Text, wait: Wait, stuck: bool, engineering: bool) -> None:
        """`stuck`: said in words (on a short screen the step's ✗ and the title say it)."""
        if stuck:
            text.append("  ")
            text.append_text(tag("stuck:", Level.ALARM))
            text.append(" ")
        else:
            text.append("  ↳ ", style=MUTED)
        if not engineering and self.words is not None:
            text.append(f"waits for {self.words(wait)}")
        else:
            text.append(f"waits for {wait.condition}")
            shown = wait.shown_values
            if shown:
                text.append(f" — {shown}")
        if wait.holds:
            text.append(f" {OK_SYMBOL} met", style=MUTED)
        text.append("\n")

    def render_frame(self, frame: Frame) -> Text:
        snap = frame.snapshot
        active = set(snap.active_steps)
        self._waits_shown = self._placed(snap.waits, active) if active else {}
        width = max(20, self.content_size.width or 40)
        engineering = frame.engineering or self.words is None
        name_w = max((len(s.name) for s in self.steps), default=2) if engineering else -1
        text = Text(no_wrap=True, overflow="ellipsis")
        # in recovery mode the procedure drives the outputs and the program waits; it starts
        # again from its initial steps when recovery is left: its steps are held, not running
        held = (frame.mode_commanded or snap.mode) == "recovery"
        if frame.manual_keys:  # (the program waits from the command on)
            text.append_text(tag("waiting — manual mode", Level.ATTENTION))
            text.append(": resumes from here\n" if self.steps else ": memories held\n",
                        style=MUTED)
        elif held:
            text.append_text(tag("waiting — recovery", Level.ATTENTION))
            text.append(": it drives the outputs; the program starts again at its first "
                        "step when you leave recovery\n", style=MUTED)
        if not self.steps:
            text.append("no GRAFCET (equations only)\n", style=MUTED)
        compact = self.compact
        stuck = len(snap.overdue_steps)
        set_title(self, f"Control · {self.control}" + (
            f" · {len(active)}/{len(self.steps)}" + ("" if stuck else " active")
            if compact else "") + (f" · {SYMBOL[Level.ALARM]} stuck" if stuck else ""))
        for step in self.steps:
            on = step.name in active
            if compact and not on:
                continue
            desc_w = max(0, width - name_w - 3 - 10)
            desc = cut(step.description, desc_w).ljust(desc_w)
            if on:
                elapsed = snap.value(step.name + ".t") if (step.name + ".t") in \
                    snap.layout.slots else 0
                stuck = step.name in snap.overdue_steps
                mark = STYLE[Level.ALARM] if stuck else Style(bold=True)
                if held:  # where the program stopped: held, and nothing it waits for counts
                    text.append(f"‖ {step.name.ljust(name_w) + ' ' if engineering else ''}"
                                f"{cut(step.description, desc_w)} (held)\n", style=MUTED)
                    continue
                text.append(f"{SYMBOL[Level.ALARM] if stuck else '●'} ", style=mark)
                if engineering:
                    text.append(f"{step.name.ljust(name_w)} ", style="bold")
                text.append(desc, style="bold")
                text.append(f" {_secs(int(elapsed))}\n", style=mark)
                for wait in self._waits_shown.get(step.name, ()):
                    late = any(s in snap.overdue_steps
                               for s in (wait.step, *self._sources(wait)))
                    self._wait_line(text, wait, late and not compact, engineering)
            else:
                text.append(f"○ {step.name.ljust(name_w) + ' ' if engineering else ''}{desc}"
                            "\n", style=MUTED)
        timer_w = max((len(t.name) for t in self.timers), default=0)
        plain_w = max((len(_plain_timer(t)) for t in self.timers), default=0)
        for state in snap.timers:
            if compact and not state.q and not state.elapsed_us:
                continue  # short and shared: idle timers give their rows to the column
            info = next((t for t in self.timers if t.name == state.name), None)
            kind = info.kind if info else "TON"
            if not engineering:  # a timer by what it times, not by its name and type
                if info is None or not _plain_timer(info):
                    continue
                text.append(f"{_plain_timer(info).ljust(plain_w)} ", style=MUTED)
                text.append(timer_bar(state.elapsed_us, state.preset_us))
                text.append(f" {timer_time(state.elapsed_us, state.preset_us)}")
                text.append("  done\n" if state.q else "\n", style="bold" if state.q else "")
                continue
            text.append(f"{state.name.ljust(timer_w)} {kind} ", style=MUTED)
            text.append(timer_bar(state.elapsed_us, state.preset_us))
            text.append(f" {timer_time(state.elapsed_us, state.preset_us)}")
            text.append(f"  Q {int(state.q)}\n", style="bold" if state.q else "")
        text.rstrip()
        return text


def cut(text: str, width: int) -> str:
    """`text` in `width` columns, ending in … when cut ("Closing for a fixed 3 s, open order
    still on at first" read "Closing for a fixed 3 s," at 80 columns: a sentence that says
    something else, not one visibly cut)."""
    return text if len(text) <= width else (text[: width - 1] + "…" if width > 0 else "")
