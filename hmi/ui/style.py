"""ISA-101 display conventions, in one place so every widget speaks the same visual language.

Normal states are drawn in quiet greys without colour. Colour is kept for what is abnormal,
and every colour is doubled by a symbol and a word, so that the display still reads on a
monochrome terminal, in a screenshot printed in black and white, or to a colour-blind
operator:

- attention (amber, ``▲``): off-normal but intended — manual mode, forces, paused, an output
  changed by the filter, a sensor running on its reconstruction, the monitor policy;
- alarm (red, ``✗``): the cell needs the operator — outputs latched safe, plant disconnected,
  a refused command, a masked actuator;
- simulation (reverse video, the word ``SIMULATION``): a training or commissioning action
  that a real plant would not offer.
"""

from __future__ import annotations

from enum import Enum
from typing import TYPE_CHECKING

from rich.style import Style
from rich.text import Text

if TYPE_CHECKING:
    from textual.theme import Theme


class Level(Enum):
    NORMAL = "normal"
    ATTENTION = "attention"
    ALARM = "alarm"
    SIMULATION = "simulation"


SYMBOL = {
    Level.NORMAL: "",
    Level.ATTENTION: "▲",
    Level.ALARM: "✗",
    Level.SIMULATION: "◇",
}

STYLE = {
    Level.NORMAL: Style(),
    Level.ATTENTION: Style(color="#e8a317", bold=True),
    Level.ALARM: Style(color="#ff6b6b", bold=True),
    Level.SIMULATION: Style(reverse=True),
}

BANNER_STYLE = {
    Level.NORMAL: Style(),
    Level.ATTENTION: Style(color="#1c1c1c", bgcolor="#e8a317", bold=True),
    Level.ALARM: Style(color="#ffffff", bgcolor="#b03030", bold=True),
    Level.SIMULATION: Style(reverse=True, bold=True),
}

MUTED = Style(color="#8a8a8a")
OK_SYMBOL = "✓"


def tag(word: str, level: Level) -> Text:
    """A word with its level's symbol and colour: never colour alone.

    The style is a span, not the Text's base style, so that text appended after the tag
    (a reason, a detail) stays in the quiet default colour.
    """
    symbol = SYMBOL[level]
    return Text.assemble((f"{symbol} {word}" if symbol else word, STYLE[level]))


def banner(word: str, level: Level) -> Text:
    symbol = SYMBOL[level]
    return Text(f" {symbol} {word} {symbol} " if symbol else f" {word} ",
                style=BANNER_STYLE[level])


def bit(value: object) -> str:
    """A Boolean as the digit engineers read in a PLC's I/O table."""
    return "1" if value else "0"


ISA101 = "isa101"  # the theme's name


def isa101_theme() -> Theme:
    """A grey Textual theme: accents are greys, so only abnormal states carry colour."""
    from textual.theme import Theme

    return Theme(
        name=ISA101,
        primary="#9a9a9a",
        secondary="#7a7a7a",
        accent="#b0b0b0",
        warning="#e8a317",
        error="#ff6b6b",
        success="#9a9a9a",
        foreground="#d4d4d4",
        background="#262626",
        surface="#2c2c2c",
        panel="#383838",
        dark=True,
        variables={
            "footer-key-foreground": "#e0e0e0",
            "block-cursor-background": "#5a5a5a",
            "block-cursor-foreground": "#ffffff",
            "block-cursor-text-style": "bold",
            "input-selection-background": "#5a5a5a",
        },
    )


def gap(text: Text, width: int = 2) -> Text:
    """Append a gap of `width` spaces that closes the text's last run (in its style, which
    must have no background): the SVG screenshots are read by viewers that drop the spaces
    opening a run, and would run the next column into this one (`P110.830 s`, `V1A3`)."""
    last = text.spans[-1] if text.spans else None
    style = last.style if last is not None and last.end == len(text) else text.style
    text.append(" " * width, style=style)
    return text
