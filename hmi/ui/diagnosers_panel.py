"""Local diagnosers (000 §2.1, §3.1): each one's state, decision, flags, and what they drive.

Per diagnoser::

    ✗ V1  A1 fsc never made although the valve should be closed · since 15.750 s
      {F1, F13} ? ambiguous  F1 sensor fsc stuck at 0 · F13 valve blocked between …

(a certain decision: ``F4 ✗ certain  sensor fso stuck at 1``)
      flags ▲ def_fsc  def_fso  ✗ def_V
      ≈ fsc from fsc_hat   ⊘ C, O masked (def_V)

A diagnoser in a normal state is grey (``●`` and its state); a certain decision reads
``F4 ✗ certain``, an ambiguous one ``{F1, F13} ? ambiguous`` (``not yet isolated`` while an
intermediate state may still refine it). Flags are words: a set sensor flag is amber with
``▲`` (the sensor runs on its estimate), a set actuator flag red with ``✗`` (its orders are
masked). The last line repeats what the flags do to the I/O, which the I/O table also marks
on the rows concerned.

When the column is short, the label texts go first, then the flags line, down to one line
per diagnoser (state and decision).
"""

from __future__ import annotations

from dataclasses import dataclass

from rich.style import Style
from rich.text import Text

from hmi.engine.diagnoser import DiagnoserState
from hmi.timefmt import seconds
from hmi.ui.frame import Frame
from hmi.ui.panel import ColumnPanel, set_title
from hmi.ui.style import MUTED, STYLE, Level, gap


@dataclass(frozen=True)
class PartitionInfo:
    """What the UI knows of a partition from the project (static)."""

    flag: str
    sensor: str | None
    estimate: str | None
    actuators: tuple[str, ...]
    # the operator's words (hmi.explain.plain): the part ("closed end switch"), its sensor,
    # its orders
    words: str = ""
    sensor_words: str = ""
    actuator_words: tuple[str, ...] = ()


def decision_cell(labels: tuple[str, ...], final: bool) -> Text:
    """`F4 ✗ certain`, `{F1, F13} ? ambiguous`, `{F1, F8, F11} ? not yet isolated`."""
    text = Text()
    if len(labels) == 1:
        text.append(f"{labels[0]} ✗ certain", style=STYLE[Level.ALARM])
    else:
        word = "ambiguous" if final else "not yet isolated"
        text.append("{" + ", ".join(labels) + "} ", style=STYLE[Level.ALARM])
        text.append(f"? {word}", style=STYLE[Level.ATTENTION])
    return text


def flags_text(flags: tuple[tuple[str, bool], ...], partitions: dict[str, PartitionInfo]
               ) -> Text:
    text = Text("flags", style=MUTED)
    for name, value in flags:
        text.append(" ")
        if not value:
            text.append(" ").append(name, style=MUTED)
            continue
        info = partitions.get(name)
        level = Level.ALARM if info is not None and info.actuators else Level.ATTENTION
        symbol = "✗" if level is Level.ALARM else "▲"
        text.append(f"{symbol} {name}", style=STYLE[level])
    return text


def plain_flags_text(flags: tuple[tuple[str, bool], ...],
                     partitions: dict[str, PartitionInfo]) -> Text | None:
    """The operator's flags line: only the parts distrusted, by their words."""
    text = Text()
    for name, value in flags:
        info = partitions.get(name)
        if not value or info is None:
            continue
        level = Level.ALARM if info.actuators else Level.ATTENTION
        if text:
            gap(text, 2)
        else:
            text.append("distrusted: ", style=MUTED)
        text.append(f"{'✗' if level is Level.ALARM else '▲'} {info.words or name}",
                    style=STYLE[level])
    return text or None


def effects_text(flags: tuple[tuple[str, bool], ...], partitions: dict[str, PartitionInfo],
                 reconstructed: set[str], masked: set[str], engineering: bool = True
                 ) -> Text | None:
    """What the set flags do now: sensors read from their estimate, orders masked."""
    text = Text()
    for name, value in flags:
        info = partitions.get(name)
        if not value or info is None:
            continue
        if info.sensor and info.sensor in reconstructed:
            if text:
                gap(text, 3)
            text.append(f"≈ {info.sensor} from {info.estimate}" if engineering else
                        f"≈ {info.sensor_words or info.sensor} estimated",
                        style=STYLE[Level.ATTENTION])
        outs = [o for o in info.actuators if o in masked]
        words = dict(zip(info.actuators, info.actuator_words, strict=False))
        if outs:
            if text:
                gap(text, 3)
            text.append(f"⊘ {', '.join(outs)} masked ({name})" if engineering else
                        f"⊘ {', '.join(words.get(o, o) for o in outs)} held at 0",
                        style=STYLE[Level.ALARM])
        elif info.actuators:
            if text:
                gap(text, 3)
            text.append(f"{', '.join(info.actuators)} not masked ({name}: monitor policy or "
                        "observe mode)" if engineering else
                        f"{', '.join(words.get(o, o) for o in info.actuators)} still driven "
                        "(monitor policy or observe mode)", style=MUTED)
    return text or None


def plain_lines(d: DiagnoserState, partitions: dict[str, PartitionInfo], reconstructed: set[str],
                masked: set[str], detail: int) -> list[Text]:
    """The operator's view of a diagnoser: its device, what it sees, the suspected faults
    in words, what it distrusts and what that does; no state, label or flag names."""
    head = Text()
    device = d.device or d.name
    if d.faulty:
        head.append(f"✗ {device}: ", style=STYLE[Level.ALARM])
    else:
        head.append(f"● {device}: ", style=Style(bold=True))
    head.append(d.description or ("fault suspected" if d.faulty else "normal"),
                style=None if d.faulty else MUTED)
    if detail == 0:
        return [head]
    head.append(f" · since {seconds(d.since_us)} s", style=MUTED)
    lines = [head]
    if d.faulty:
        line = Text("  ")
        if len(d.labels) == 1:
            line.append("certain: ", style=STYLE[Level.ALARM])
        else:
            line.append("ambiguous: " if d.final else "not yet isolated: ",
                        style=STYLE[Level.ATTENTION])
        line.append(" or ".join(d.label_texts), style=STYLE[Level.ALARM])
        lines.append(line)
    flags = plain_flags_text(d.flags, partitions)
    if flags is not None:
        lines.append(Text("  ").append_text(flags))
    effects = effects_text(d.flags, partitions, reconstructed, masked, engineering=False)
    if effects is not None and detail >= 2:
        lines.append(Text("  ").append_text(effects))
    return lines


def diagnoser_lines(d: DiagnoserState, partitions: dict[str, PartitionInfo],
                    reconstructed: set[str], masked: set[str], name_w: int,
                    detail: int) -> list[Text]:
    # Each gap ends the run before it (`V1 ` then `A3 `), so no viewer runs them together.
    head = Text()
    if d.faulty:
        head.append(f"✗ {d.name.ljust(name_w)} ", style=STYLE[Level.ALARM])
    else:
        head.append(f"● {d.name.ljust(name_w)} ", style=Style(bold=True))
    head.append(f"{d.state} ", style=Style(bold=True))
    if detail == 0:
        if d.faulty:
            gap(head.append_text(decision_cell(d.labels, d.final)), 1)
        head.append(d.description, style=MUTED)
        return [head]
    if d.description:
        head.append(f"{d.description} ")
    head.append(f"· since {seconds(d.since_us)} s", style=MUTED)
    lines = [head]
    if d.faulty:
        line = Text("  ")
        line.append_text(decision_cell(d.labels, d.final))
        if detail >= 2:
            gap(line)
            line.append(d.label_texts[0] if len(d.labels) == 1 else " · ".join(
                f"{lab} {text}" for lab, text in zip(d.labels, d.label_texts, strict=True)))
        lines.append(line)
    if d.flags:
        lines.append(Text("  ").append_text(flags_text(d.flags, partitions)))
    effects = effects_text(d.flags, partitions, reconstructed, masked)
    if effects is not None and detail >= 2:
        lines.append(Text("  ").append_text(effects))
    return lines


class DiagnosersPanel(ColumnPanel):
    """Every local diagnoser of the project; hidden when it has none."""

    def __init__(self, partitions: dict[str, PartitionInfo], count: int, *,
                 id: str | None = None):
        super().__init__(id=id)
        self.partitions = partitions
        self.count = count
        self.display = count > 0

    def on_mount(self) -> None:
        self.border_title = f"Diagnosers · {self.count}"

    def min_lines(self) -> int:
        return max(1, self.count)

    def render_detail(self, frame: Frame, detail: int) -> Text:
        snap = frame.snapshot
        text = Text(no_wrap=True, overflow="ellipsis")
        if not snap.diagnosers:
            text.append("no diagnoser state yet", style=MUTED)
            return text
        faulty = sum(1 for d in snap.diagnosers if d.faulty)
        set_title(self, f"Diagnosers · {len(snap.diagnosers)}"
                  + (f" · {faulty} faulty" if faulty else ""))
        name_w = max(len(d.name) for d in snap.diagnosers)
        reconstructed, masked = set(snap.reconstructed), set(snap.masked)
        lines = [line for d in snap.diagnosers
                 for line in (diagnoser_lines(d, self.partitions, reconstructed, masked,
                                              name_w, detail) if frame.engineering else
                              plain_lines(d, self.partitions, reconstructed, masked, detail))]
        return Text("\n", no_wrap=True, overflow="ellipsis").join(lines)
