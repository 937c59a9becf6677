"""``plchmi soak PROJECT``: the whole HMI driven by a seeded random operator (the soak itself
and its options are in hmi/soak/)."""

from __future__ import annotations

import argparse

from hmi.cli.options import project_arg


def add_parser(sub) -> None:
    from hmi.soak.command import add_soak_parser
    add_soak_parser(sub, project_arg)


def cmd_soak(args: argparse.Namespace) -> int:
    from hmi.soak.command import cmd_soak
    return cmd_soak(args)
