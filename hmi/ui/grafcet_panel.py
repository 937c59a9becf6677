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
"""

from __future__ import annotations

from dataclasses import dataclass

from rich.text import Text

from hmi.timefmt import format_duration
from hmi.ui.frame import Frame
from hmi.ui.panel import TextPanel, set_title
from hmi.ui.style import MUTED, Level, tag

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


def _secs(us: int) -> str:
    return f"{us / 1_000_000:6.2f} s"


def timer_bar(elapsed_us: int, preset_us: int, width: int = BAR) -> str:
    filled = 0 if preset_us <= 0 else min(width, elapsed_us * width // preset_us)
    return "▕" + "█" * filled + "·" * (width - filled) + "▏"


class GrafcetPanel(TextPanel):
    def __init__(self, control: str, steps: list[StepInfo], timers: list[TimerInfo], *,
                 id: str | None = None):
        super().__init__(id=id)
        self.control = control
        self.steps = steps
        self.timers = timers
        self.frame: Frame | None = None

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

    def render_frame(self, frame: Frame) -> Text:
        snap = frame.snapshot
        active = set(snap.active_steps)
        width = max(20, self.content_size.width or 40)
        name_w = max((len(s.name) for s in self.steps), default=2)
        text = Text(no_wrap=True, overflow="ellipsis")
        if frame.manual_keys:  # (the program waits from the command on)
            text.append_text(tag("waiting — manual mode", Level.ATTENTION))
            text.append(": resumes from here\n" if self.steps else ": memories held\n",
                        style=MUTED)
        if not self.steps:
            text.append("no GRAFCET (equations only)\n", style=MUTED)
        compact = self.compact
        set_title(self, f"Control · {self.control}" + (
            f" · {len(active)}/{len(self.steps)} active" if compact else ""))
        for step in self.steps:
            on = step.name in active
            if compact and not on:
                continue
            desc_w = max(0, width - name_w - 3 - 10)
            desc = step.description[:desc_w].ljust(desc_w)
            if on:
                elapsed = snap.value(step.name + ".t") if (step.name + ".t") in \
                    snap.layout.slots else 0
                text.append(f"● {step.name.ljust(name_w)} ", style="bold")
                text.append(desc, style="bold")
                text.append(f" {_secs(int(elapsed))}\n", style="bold")
            else:
                text.append(f"○ {step.name.ljust(name_w)} {desc}\n", style=MUTED)
        timer_w = max((len(t.name) for t in self.timers), default=0)
        for state in snap.timers:
            if compact and not state.q and not state.elapsed_us:
                continue  # short and shared: idle timers give their rows to the column
            info = next((t for t in self.timers if t.name == state.name), None)
            kind = info.kind if info else "TON"
            text.append(f"{state.name.ljust(timer_w)} {kind} ", style=MUTED)
            text.append(timer_bar(state.elapsed_us, state.preset_us))
            text.append(f" {state.elapsed_us / 1e6:4.2f}/{format_duration(state.preset_us)}")
            text.append(f"  Q {int(state.q)}\n", style="bold" if state.q else "")
        text.rstrip()
        return text
