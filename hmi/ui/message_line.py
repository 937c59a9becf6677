"""The answer to the operator's last action, on one line above the footer.

Every command gets an answer at once: accepted (``✓``) or refused (``✗ REFUSED`` in red, with
the engine's reason). A manual request gets a second answer when the next scan has run:
whether the value written to the plant is the one requested, and if not, why.
"""

from __future__ import annotations

from collections.abc import Callable

from rich.text import Text

from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    Command,
    CommandResult,
    CommentAlarm,
    SetMode,
    Shelve,
    StartRecovery,
    Unshelve,
    describe,
)
from hmi.ui.panel import TextPanel
from hmi.ui.style import OK_SYMBOL, Level, tag


def spoken(command: Command, result: CommandResult,
           text_of: Callable[[str], str]) -> tuple[str, str]:
    """(what, answer) as the operator reads them. The journal keeps the commands' stable
    identifiers (``describe``: "acknowledge alarm constraint:CSs2", "start recovery
    V1_close"); the message line names a situation by its text, as the alarm list does
    (`text_of`: a situation's key -> its one-line text), and leaves out what the answer
    already says in plain words (the recovery's title, the policy's label)."""
    what, message = describe(command), result.message
    match command:
        case ChoosePolicy(key=key):  # "policy 'Continue' chosen for KEY: ...": the panel
            return "policy", message.replace(f" for {key}", "", 1)  # shows the subject
        case Acknowledge(key=str() as key) if result.accepted:
            return "acknowledged", f"{message}: {text_of(key)}"
        case StartRecovery():  # the answer names the procedure by its title
            return "start recovery", message
        case SetMode() if result.accepted:  # 'manual mode: the control program waits...'
            return message.split(":", 1)[0], message  # names the mode: not told twice
        case Acknowledge(key=str() as key) | Shelve(key=key) | Unshelve(key=key) \
                | CommentAlarm(key=key):
            text = text_of(key)
            named = f"“{text}”"
            # an answer that names the alarm already ('already acknowledged: TEXT',
            # 'TEXT: back in the list') is not told its text a second time
            what = what.replace(f" {key}", "") if text in message else \
                what.replace(key, named)
            return what, message.replace(key, named)
    return what, message


def result_text(what: str, result: CommandResult, message: str | None = None) -> Text:
    """'✓ fault reset: nothing was latched'; the command's words once, not twice when the
    answer already starts with them ('fault reset: fault reset: ...', 'speed: x1: speed:
    x1'). `message`: the answer as the operator reads it (:func:`spoken`), if not the
    command's own."""
    message = result.message if message is None else message
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
