"""``plchmi PROJECT`` (``plchmi ui PROJECT``): the operator HMI of the project's cell. The
cell's runtime runs in a process of its own (hmi.cli.screens): started here if none runs,
then this screen attaches to it. With --opcua the runtime starts its OPC UA gateway beside it
(hmi.cli.gateway), a process of its own."""

from __future__ import annotations

import argparse
import gc
from typing import TYPE_CHECKING

from hmi.cli.options import project_arg
from hmi.codecache import dataclass_code

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers


def add_parser(sub: Subparsers) -> None:
    from hmi.cli.screens import runtime_args
    p = sub.add_parser("ui", help="open the operator HMI (the default command): the cell's "
                       "runtime is started if none runs, and this screen attaches to it")
    project_arg(p)
    runtime_args(p)
    p.add_argument("--bell", action="store_true",
                   help="ring the terminal bell when a new unacknowledged P1 alarm appears")
    from hmi.opcua.options import add_arguments as opcua_args
    opcua_args(p)


def cmd_ui(args: argparse.Namespace) -> int:
    # The start (docs/performance.md): no garbage collection until the screen runs (the
    # start allocates much and frees little; hmi.ui.driver.LiveDriver.start collects once,
    # freezes what exists and turns it back on), the code of the generated dataclass
    # methods read from its cache instead of compiled again (hmi/codecache.py), the project
    # read back as loaded before (hmi/project/kept.py).
    gc.disable()
    try:
        with dataclass_code():
            from hmi.opcua.options import check_arguments
            check_arguments(args)  # (--opcua: the runtime's gateway serves it)
            import hmi.ui.app  # noqa: F401  (the HMI's modules: their classes built here)
            from hmi.cli.screens import given_runtime_options, run_screen, start_runtime
            from hmi.errors import UsageError
            from hmi.project import kept
            from hmi.runtime.place import place, running
            project = kept.load(args.project, getattr(args, "diagnoser", None))
            where = place(project.name, args.socket)
            pid = running(where)
            if pid is None:
                start_runtime(args, project, where)
            else:
                given = given_runtime_options(args)
                if given:
                    raise UsageError(
                        f"{project.name} already runs (runtime pid {pid}) with the options it "
                        f"was started with; {' '.join(given)} cannot change it: attach "
                        f"(plchmi {args.project}), or stop it first")
        return run_screen(args, project, where.socket)
    finally:
        gc.enable()
