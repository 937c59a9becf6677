"""Messages the panels send up to the app ("attributes down, messages up").

A panel never calls the session: it asks the app to send a command, so that every operator
action goes through one place (``PlcHmiApp.send`` → ``Session.command``), where the
journal will listen.
"""

from __future__ import annotations

from textual.message import Message

from hmi.engine.commands import Command


class CommandRequested(Message):
    """A panel asks the app to send an operator command to the session."""

    def __init__(self, command: Command) -> None:
        super().__init__()
        self.command = command


class ExplainRequested(Message):
    """Explain a situation (by its key), e.g. a constraint clicked in its panel."""

    def __init__(self, key: str, open_level: int = 2) -> None:
        super().__init__()
        self.key = key
        self.open_level = open_level
