"""The answer to the operator's last action, on one line above the footer.

Every command gets an answer at once: accepted (``✓``) or refused (``✗ REFUSED`` in red, with
the engine's reason). A manual request gets a second answer when the next scan has run:
whether the value written to the plant is the one requested, and if not, why.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

from rich.text import Text

from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    Command,
    CommandResult,
    CommentAlarm,
    FaultReset,
    InjectFault,
    RepairFaults,
    SetMode,
    Shelve,
    StartRecovery,
    Unshelve,
    describe,
)
from hmi.explain.plain import without_notes
from hmi.explain.reset import ResetLine
from hmi.project.injection import Injection
from hmi.timefmt import seconds
from hmi.ui.panel import TextPanel
from hmi.ui.style import OK_SYMBOL, Level, tag


@dataclass(frozen=True)
class Words:
    """What the operator view says instead of the model's names (None: the engineering
    view, the engine's own answers): a simulated fault by its description, a fault reset by
    the preview the operator confirmed."""

    fault_text: Callable[[Injection], str]
    reset_shown: list[ResetLine] | None = None
    steps: Mapping[str, str] = field(default_factory=dict)  # step -> its description
    # a policy's answer: what it carried out (its answer then said as that command's)
    inner: Command | None = None


def spoken(command: Command, result: CommandResult,
           text_of: Callable[[str], str], words: Words | None = None) -> tuple[str, str]:
    """(what, answer) as the operator reads them. The journal keeps the commands' stable
    identifiers (``describe``: "acknowledge alarm constraint:CSs2", "start recovery
    V1_close"); the message line names a situation by its text, as the alarm list does
    (`text_of`: a situation's key -> its one-line text), and leaves out what the answer
    already says in plain words (the recovery's title, the policy's label)."""
    what, message = describe(command), result.message
    if words is not None and words.inner is not None and isinstance(command, ChoosePolicy):
        head, found, rest = message.partition(f" for {command.key}: ")
        if found:  # "policy 'Fault reset' chosen: released: …", not the engine's words
            inner_what, inner_answer = spoken(words.inner, CommandResult(result.accepted, rest),
                                              text_of, replace(words, inner=None))
            return "policy", f"{head}: {said(inner_what, inner_answer)}"
    if words is not None and isinstance(command, FaultReset) and not result.accepted \
            and message.startswith("not done, asked again"):  # the dialog says what changed
        return "fault reset", message.split(" (scan", 1)[0] + "; the dialog says how"
    if words is not None and result.accepted:
        match command:
            case InjectFault(injection=i):
                during = f" for {seconds(i.duration_us)} s" if i.duration_us else ""
                return "SIMULATION", (f"fault at {seconds(i.at_us)} s{during}: "
                                      f"{without_notes(words.fault_text(i))}")
            case RepairFaults():  # 'valve repaired (F13 removed)': by the faults' words
                removed = [without_notes(words.fault_text(Injection(code.strip(), 0, device)))
                           for device, codes in re.findall(r"(\S+) repaired \(([^()]*) removed\)",
                                                           message)
                           for code in codes.split(",")]
                return "SIMULATION", ("repaired" + (f" ({'; '.join(removed)} removed)"
                                                    if removed else "")
                                      + "; next: a fault reset (r), which says first what it "
                                        "resets and what stays")
            case SetMode() if words.steps:  # 'waits at “Open, filling” (X2)': its words
                message = re.sub(r" \((\w+)\)", lambda m: "" if m.group(1) in words.steps
                                 else m.group(0), message)
                message = re.sub(r"[\w.]+", lambda m: f"\u201c{words.steps[m.group(0)]}\u201d"
                                 if m.group(0) in words.steps else m.group(0), message)
                return message.split(":", 1)[0], message
            case FaultReset() if words.reset_shown is not None:
                done = [line.what for line in words.reset_shown if line.resets]
                kept = [line.what for line in words.reset_shown if not line.resets]
                return "fault reset", "; ".join(
                    [*(["released: " + "; ".join(done)] if done else []),
                     *(["stays: " + "; ".join(kept)] if kept else [])]) or "nothing was latched"
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


def said(what: str, message: str) -> str:
    """'what: message', or the message alone when it starts with what it answers."""
    return message if message.lower().startswith(what.lower()) else f"{what}: {message}"


def result_text(what: str, result: CommandResult, message: str | None = None) -> Text:
    """'✓ fault reset: nothing was latched'; the command's words once, not twice when the
    answer already starts with them ('fault reset: fault reset: ...', 'speed: x1: speed:
    x1'). `message`: the answer as the operator reads it (:func:`spoken`), if not the
    command's own."""
    body = said(what, result.message if message is None else message)
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
