"""What the soak's operator does, one concrete step at a time, and the text form of a step list.

A step is concrete (the keys pressed, the palette entry's exact title, the virtual time run),
never "something random": a list of steps replays the same session on a fresh app, which is
what makes a failure reproducible and shrinkable. The text form, one step a line, is what
``plchmi soak`` prints on a failure and what ``--replay FILE`` reads::

    run 1.250s
    press r y
    palette Manual: O on  [1]
    row O
    click #constraints 3 1
    resize 100x30
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass

from hmi.limits import MAX_RUN_SCANS
from hmi.timefmt import format_duration, parse_duration, seconds


@dataclass(frozen=True)
class Run:
    """Run virtual time (nothing happens while paused), as fast as the machine goes."""

    us: int

    def text(self) -> str:
        return f"run {seconds(self.us)}s"


@dataclass(frozen=True)
class Press:
    """Keys, as Textual names them (``r``, ``y``, ``escape``, ``shift+tab``, ``space``)."""

    keys: tuple[str, ...]

    def text(self) -> str:
        return "press " + " ".join(self.keys)


@dataclass(frozen=True)
class Palette:
    """The command palette (ctrl+p), the entry with this exact title run."""

    title: str

    def text(self) -> str:
        return f"palette {self.title}"


@dataclass(frozen=True)
class Row:
    """A click on the I/O table's row of this signal (selects it, focuses the table)."""

    name: str

    def text(self) -> str:
        return f"row {self.name}"


@dataclass(frozen=True)
class Click:
    """A click in a widget (CSS selector), at an offset from its top-left corner."""

    selector: str
    x: int
    y: int

    def text(self) -> str:
        return f"click {self.selector} {self.x} {self.y}"


@dataclass(frozen=True)
class Resize:
    """The terminal resized."""

    width: int
    height: int

    def text(self) -> str:
        return f"resize {self.width}x{self.height}"


Step = Run | Press | Palette | Row | Click | Resize


class StepError(ValueError):
    """A line of a step list that is not a step (line number and what was expected)."""


def parse_size(text: str) -> tuple[int, int]:
    """'80x24' -> (80, 24)."""
    width, sep, height = text.lower().partition("x")
    if not sep or not width.isdigit() or not height.isdigit():
        raise ValueError(f"{text!r} is not a terminal size such as 80x24")
    return int(width), int(height)


def parse_step(line: str) -> Step:
    word, _, rest = line.strip().partition(" ")
    rest = rest.strip()
    match word:
        case "run":
            return Run(parse_duration(rest))
        case "press":
            keys = tuple(rest.split())
            if not keys:
                raise ValueError("press needs at least one key")
            return Press(keys)
        case "palette":
            if not rest:
                raise ValueError("palette needs an entry's title")
            return Palette(rest)
        case "row":
            if not rest:
                raise ValueError("row needs a signal name")
            return Row(rest)
        case "click":
            parts = shlex.split(rest)
            if len(parts) != 3 or not all(p.lstrip("-").isdigit() for p in parts[1:]):
                raise ValueError("click needs a selector and two offsets: click #io 3 1")
            return Click(parts[0], int(parts[1]), int(parts[2]))
        case "resize":
            return Resize(*parse_size(rest))
    raise ValueError(f"unknown step {word!r}; steps: run, press, palette, row, click, resize")


def parse_steps(text: str, source: str = "steps", period_us: int | None = None) -> list[Step]:
    """A step list; blank lines and `#` comments are skipped. With `period_us`, the steps may
    run at most MAX_RUN_SCANS scans of that period in all (the first past it is an error)."""
    steps: list[Step] = []
    total = 0
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            step = parse_step(line)
        except ValueError as exc:
            raise StepError(f"{source}:{number}:1: {exc}") from None
        if isinstance(step, Run) and period_us is not None:
            total += step.us
            if total // period_us + 1 > MAX_RUN_SCANS:
                raise StepError(
                    f"{source}:{number}:1: the steps run {format_duration(total)} of virtual "
                    f"time up to here, {total // period_us + 1:,} scans at a "
                    f"{format_duration(period_us)} scan period: more than the "
                    f"{MAX_RUN_SCANS:,} plchmi runs at once")
        steps.append(step)
    return steps


def format_steps(steps: list[Step]) -> str:
    return "".join(step.text() + "\n" for step in steps)


def steps_header(project: object, control: str | None, size: tuple[int, int], seed: int,
                 why: str, split: bool = False) -> str:
    """A saved step list's first two lines: the soak command that found it, to copy (no
    --control for the project's default variant; --split when the HMI was attached over
    the socket, whose timing of frames a replay must reproduce), then what broke."""
    option = (f" --control {control}" if control else "") + (" --split" if split else "")
    return f"# plchmi soak {project}{option} --size {size[0]}x{size[1]} --seed {seed}\n# {why}\n"
