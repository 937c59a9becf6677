"""``plchmi users``: the users file (hmi/access/users.py, docs/security.md).

    plchmi users add NAME --role viewer|operator|engineer
    plchmi users passwd NAME          plchmi users role NAME ROLE
    plchmi users lock NAME            plchmi users unlock NAME
    plchmi users remove NAME          plchmi users list

A password is read twice from the terminal, or once from standard input with --stdin; only
its argon2id hash is written. `unlock` also ends a lockout after wrong passwords.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.errors import UsageError

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("users", help="who may sign in, and their roles (docs/security.md)",
                       description="Manage the users file that every door (terminal, "
                       "browser, OPC UA) signs in against. There are no default users: "
                       "until one is added nobody can sign in, the local terminal works "
                       "without sign-in and every remote door is refused.")
    p.add_argument("--file", type=Path, metavar="FILE",
                   help="the users file (default: $PLCHMI_DATA/users)")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    add = actions.add_parser("add", help="add a user")
    add.add_argument("name")
    add.add_argument("--role", required=True, choices=("viewer", "operator", "engineer"))
    add.add_argument("--stdin", action="store_true",
                     help="read the password from the first line of standard input")
    passwd = actions.add_parser("passwd", help="change a user's password")
    passwd.add_argument("name")
    passwd.add_argument("--stdin", action="store_true",
                        help="read the password from the first line of standard input")
    role = actions.add_parser("role", help="change a user's role")
    role.add_argument("name")
    role.add_argument("role", choices=("viewer", "operator", "engineer"))
    for action, text in (("lock", "lock an account (nobody signs in as it until unlocked)"),
                         ("unlock", "unlock an account, and end a lockout after wrong "
                          "passwords"), ("remove", "remove a user")):
        actions.add_parser(action, help=text).add_argument("name")
    actions.add_parser("list", help="the users, their roles and state, and the sessions open")


def _password(name: str, stdin: bool) -> str:
    if stdin:
        return sys.stdin.readline().rstrip("\r\n")
    import getpass
    password = getpass.getpass(f"Password for {name}: ")
    if getpass.getpass("Again: ") != password:
        raise UsageError("the two passwords differ; nothing was written")
    return password


def cmd_users(args: argparse.Namespace) -> int:
    from hmi.access import users
    path = args.file or users.default_path()
    if path.is_dir():
        raise UsageError(f"--file {path}: this is a folder, not a users file")
    match args.action:
        case "add":
            users.add(path, args.name, args.role, _password(args.name, args.stdin))
            print(f"Added {args.name} ({args.role}) to {path}")
        case "passwd":
            users.find(path, args.name)
            users.change(path, args.name, password=_password(args.name, args.stdin))
            print(f"Changed the password of {args.name} in {path}")
        case "role":
            users.change(path, args.name, role=args.role)
            print(f"{args.name} is now {args.role} in {path}")
        case "lock":
            users.change(path, args.name, lock=True)
            print(f"Locked {args.name}: nobody signs in as {args.name} until "
                  f"plchmi users unlock {args.name}")
        case "unlock":
            users.change(path, args.name, lock=False)
            _forget_failures(path, args.name)
            print(f"Unlocked {args.name}")
        case "remove":
            users.remove(path, args.name)
            print(f"Removed {args.name} from {path}")
        case "list":
            _list(path)
    return 0


def _forget_failures(path: Path, name: str) -> None:
    import json

    from hmi.access.signin import Authenticator
    from hmi.access.users import locked, write_atomically
    failures = Authenticator.failures_file(path)
    with locked(path):
        try:
            state = json.loads(failures.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return
        if isinstance(state, dict) and state.pop(name, None) is not None:
            write_atomically(failures, json.dumps(state))


def _list(path: Path) -> None:
    from hmi.access import users
    from hmi.access.sessions import SessionTable
    from hmi.timefmt import format_duration
    found = users.read(path)
    if found is None:
        print(f"{path}: no users file: nobody can sign in; the local terminal works "
              "without sign-in and every remote door is refused")
        return
    s = found.settings
    print(f"{path}: {len(found.users)} user{'s' if len(found.users) != 1 else ''}; "
          f"lockout after {s.lockout_after} wrong passwords for "
          f"{format_duration(s.lockout_us)}; idle lock {format_duration(s.idle_lock_us)}; "
          f"{s.sessions_per_user} sessions per user; local terminal: {s.local_terminal}")
    open_now = SessionTable(path).list()
    for user in found.users.values():
        mine = [o.describe() for o in open_now if o.user == user.name]
        print(f"  {user.name:20} {user.role:9} {'LOCKED' if user.locked else 'active':7}"
              + (f"  open: {', '.join(mine)}" if mine else ""))
