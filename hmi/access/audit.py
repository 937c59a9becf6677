"""A sign-in that was refused, as the journal keeps it: the name tried, the door, the address
it came from, and why — never the password.

Every door that checks a password (the browser's sign-in page, the OPC UA gateway, the
terminal through the runtime) makes one of these for each refusal; the attempt that locks
the account is journalled as ``account-locked``, every other refusal as
``sign-in-refused``. The door that is attached to the runtime sends it there (the runtime
writes the cell's journal); the browser's door, a process beside the runtime, appends it
to the cell's journal itself (the journal takes writers of several processes, each entry
linked to the one before: hmi.explain.journal).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hmi.explain.journal import Journal

MAX_NAME = 64  # characters of a name tried that are journalled


def shown_name(name: str) -> str:
    """A name as typed, fit for one journal line: control characters replaced, cut."""
    cleaned = "".join(c if c.isprintable() else "?" for c in name[:MAX_NAME])
    return cleaned + ("…" if len(name) > MAX_NAME else "") or "(empty)"


@dataclass(frozen=True)
class SignInRefusal:
    user: str  # the name tried (shown_name)
    door: str  # browser, opcua, terminal
    source: str  # where from: the client's address, "local" for this machine's terminal
    reason: str  # the door's answer, in plain words
    locked: bool = False  # this attempt locked the account

    @property
    def event(self) -> str:
        return "account-locked" if self.locked else "sign-in-refused"

    @property
    def message(self) -> str:
        where = f" from {self.source}" if self.source else ""
        return f"{self.door}:{self.user}{where} was not let in: {self.reason}"

    def fields(self) -> dict[str, str]:
        """The journal entry's who and where."""
        return {"by": f"{self.door}:{self.user}", "role": "", "door": self.door,
                "user": self.user, "source": self.source}

    def entry(self) -> dict[str, object]:
        return {"type": "session", "event": self.event, "message": self.message,
                **self.fields()}


def refusal(name: str, door: str, source: str, reason: str,
            locked: bool = False) -> SignInRefusal:
    return SignInRefusal(shown_name(name), door, source, reason, locked)


def append(journal_path: Path, refused: SignInRefusal) -> None:
    """Into the cell's journal from a process that does not hold it open (the browser's
    door): opened, one linked entry, closed (the chain's anchor written)."""
    journal = Journal(journal_path)
    try:
        journal.append(refused.entry())
    finally:
        journal.close()
