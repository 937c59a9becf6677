"""Who a screen is: the runtime decides, from the users file, never from what a screen says.

A screen's Hello names a user, a role and a door; with no users file that is taken as said
(the local terminal is its login name and does all it did before any user existed: roles
are not checked, a viewer still sends nothing) except that the browser door is refused:
nobody could have signed in there. Once a users file exists:

* a password (the terminal asked for it) is checked by the
  :class:`~hmi.access.signin.Authenticator` — the lockout shared with every door;
* a ticket (the browser door checked the password on its sign-in page and started this
  screen) is redeemed once (:mod:`hmi.access.tickets`);
* the local terminal may attach without either if the file says ``local-terminal = ROLE``;
* a gateway (OPC UA) attaches as the component it is: each of its users signed in at its own
  door against the same file, and each command it sends on their behalf is checked against
  their role here.

Anything else is refused. The role is the users file's (a screen may ask for less: attached
to view, a viewer), and a session is counted against ``sessions-per-user``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from hmi.access import tickets
from hmi.access.audit import SignInRefusal, refusal
from hmi.access.sessions import SessionTable
from hmi.access.signin import Authenticator
from hmi.access.users import default_path
from hmi.errors import UsageError
from hmi.wire import messages as m

GATEWAY_DOORS = ("opcua",)  # doors whose screens send commands on behalf of their users
REMOTE_DOORS = ("browser", "opcua")
LOCAL = "this machine"  # where a screen on the runtime's socket comes from


@dataclass(frozen=True)
class Admitted:
    identity: m.Identity
    table_id: str = ""  # its entry in the session table ("" if it counts elsewhere)
    # a person proved who they are (a password, a ticket): the screen can ask it again
    # (the idle lock, the monitor password); not so for local-terminal = ROLE
    signed_in: bool = True


class Admission:
    def __init__(self, users_path: Path | None = None):
        self.users_path = users_path or default_path()
        self.auth = Authenticator(self.users_path)
        self.table = SessionTable(self.users_path)

    def admit(self, hello: m.Hello) -> Admitted | SignInRefusal:
        """Blocking (a password costs an argon2 check): the hub calls it off the loop. A
        refusal is what the journal keeps (the name tried, never the password)."""
        claimed = hello.identity
        found, why, locked = self._admit(hello)
        if found is None:
            return refusal(claimed.user, claimed.door, LOCAL, why, locked)
        return found

    def _admit(self, hello: m.Hello) -> tuple[Admitted | None, str, bool]:
        claimed = hello.identity
        try:
            users = self.auth.users()
        except UsageError as exc:  # a damaged users file: nobody is let in on a guess
            return None, f"the users file cannot be read: {exc}", False
        if users is None:
            if claimed.door == "browser":
                return None, ("nobody can sign in from a browser: there is no users file "
                              "(plchmi users add NAME --role ROLE creates it)"), False
            return Admitted(claimed), "", False
        settings = users.settings
        door = claimed.door
        if hello.ticket:
            ticket, why = tickets.redeem(self.users_path, hello.ticket)
            if ticket is None:
                return None, why, False
            user = users.users.get(ticket.user)
            if user is None or user.locked:
                return None, f"{ticket.user} may not sign in (removed or locked since)", False
            identity = m.Identity(user.name, _least(user.role, claimed.role), ticket.door,
                                  claimed.session or ticket.web_session)
            return Admitted(identity), "", False  # (the door's own session is counted)
        if hello.password:
            result = self.auth.submit(claimed.user, hello.password).result()
            if not result.accepted or result.user is None:
                return None, result.reason, result.locked_now
            role = result.user.role
        elif door == "terminal" and settings.local_terminal != "sign-in":
            role = settings.local_terminal
        elif door in GATEWAY_DOORS:
            return Admitted(claimed), "", False  # its users: checked command by command
        else:
            return None, ("sign in first: this machine has a users file (the terminal asks "
                          "for a user name and password)"), False
        identity = replace(claimed, role=_least(role, claimed.role))
        opened, why = self.table.open(identity.user, door, settings.sessions_per_user)
        if opened is None:
            return None, why, False
        return Admitted(identity, opened.id, bool(hello.password)), "", False

    def enforced(self) -> bool:
        """Whether roles are checked: a users file exists (or cannot be read: fail closed)."""
        try:
            return self.auth.users() is not None
        except UsageError:
            return True

    def vouch(self, who: m.Identity) -> m.Identity | str:
        """A gateway's user as the users file has them now (its role, or a viewer's if the
        gateway said viewer), or why they may send nothing."""
        try:
            users = self.auth.users()
        except UsageError as exc:
            return f"refused: the users file cannot be read: {exc}"
        if users is None:
            return who
        user = users.users.get(who.user)
        if user is None or user.locked:
            return f"refused: {who.user} is not a user of this machine, or is locked"
        return replace(who, role=_least(user.role, who.role))

    def left(self, admitted: Admitted) -> None:
        if admitted.table_id:
            self.table.close(admitted.table_id)

    def close(self) -> None:
        self.auth.close()


def _least(role: str, asked: str) -> str:
    """The users file's role; a viewer's if the screen attached to view."""
    return "viewer" if asked == "viewer" else role
