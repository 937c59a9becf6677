"""The answer to the operator's last action, on one line above the footer.

Every command gets an answer at once: accepted (``✓``) or refused (``✗ REFUSED`` in red, with
the engine's reason). A manual request gets a second answer when the next scan has run:
whether the value written to the plant is the one requested, and if not, why.
"""

from __future__ import annotations

from rich.text import Text

from hmi.engine.commands import CommandResult
from hmi.ui.panel import TextPanel
from hmi.ui.style import OK_SYMBOL, Level, tag


def result_text(what: str, result: CommandResult) -> Text:
    """'✓ fault reset: nothing was latched'; the command's words once, not twice when the
    answer already starts with them ('fault reset: fault reset: ...', 'speed: x1: speed:
    x1')."""
    message = result.message
    said = message.lower().startswith(what.lower())
    body = message if said else f"{what}: {message}"
    if result.accepted:
        return Text(f"{OK_SYMBOL} {body}")
    line = tag("REFUSED", Level.ALARM)
    line.append(f" {body}")
    return line


def verdict_text(ok: bool, line: str) -> Text:
    if ok:
        return Text(f"{OK_SYMBOL} {line}")
    text = tag("NOT AS REQUESTED", Level.ATTENTION)
    text.append(" " + line)
    return text


class MessageLine(TextPanel):
    def __init__(self, *, id: str | None = None):
        super().__init__(id=id)
        self.plain = ""

    def say(self, text: Text | str) -> None:
        text = Text(text) if isinstance(text, str) else text
        self.plain = text.plain
        self.show_text(text)
