"""``plchmi soak PROJECT``: the whole HMI driven by a seeded random operator. Its options are
declared here, the soak itself (hmi/soak/) is imported only when the command runs: it
imports the whole HMI, which no other command's parsing should pay for."""

from __future__ import annotations

import argparse
from pathlib import Path

from hmi.cli.options import project_arg
from hmi.timefmt import parse_duration


def add_parser(sub) -> None:
    p = sub.add_parser("soak", help="drive the whole HMI with a seeded random operator and "
                       "check its invariants after every step (virtual time)")
    project_arg(p)
    p.add_argument("--control", metavar="VARIANT",
                   help="control law variant (default: the project's first)")
    p.add_argument("--minutes", type=_minutes, default=30.0,
                   help="virtual minutes to run (default 30)")
    p.add_argument("--seed", type=int, default=1, help="the operator's random seed (1)")
    p.add_argument("--size", type=_size, default=(80, 24), metavar="WxH",
                   help="terminal size at the start (default 80x24)")
    p.add_argument("--steps", type=int, metavar="N",
                   help="stop after N steps too (a bounded run, as the tests do)")
    p.add_argument("--replay", type=Path, metavar="FILE",
                   help="run the steps of FILE (as printed on a failure) instead")
    p.add_argument("--shrink", type=_seconds, default=300.0, metavar="TIME",
                   help="time allowed to shrink a failing step list (default 5m; 0: none)")


def _size(text: str) -> tuple[int, int]:
    from hmi.soak.steps import parse_size
    try:
        width, height = parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not (40 <= width <= 500 and 10 <= height <= 200):
        raise argparse.ArgumentTypeError(f"{text}: a terminal from 40x10 to 500x200")
    return width, height


def _minutes(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of minutes") from None
    if not 0 < value <= 10_000:
        raise argparse.ArgumentTypeError(f"{text}: from more than 0 to 10000 minutes")
    return value


def _seconds(text: str) -> float:
    if text.strip() == "0":  # the help's "0: none", a bare zero without a unit
        return 0.0
    try:
        return parse_duration(text) / 1e6
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration (30s, 5m)") from None


def cmd_soak(args: argparse.Namespace) -> int:
    from hmi.soak.command import cmd_soak
    return cmd_soak(args)
