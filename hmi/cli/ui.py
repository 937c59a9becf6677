"""``plchmi PROJECT`` (``plchmi ui PROJECT``): the operator HMI, with its journal, its plant
and, if asked, the OPC UA server."""

from __future__ import annotations

import argparse
import gc
import sys
from pathlib import Path

from hmi.cli.common import ended_by
from hmi.cli.options import (
    diagnoser_arg,
    engine_args,
    historian_args,
    journal_space_arg,
    plant_args,
    project_arg,
)
from hmi.cli.session import (
    announce,
    connect_plant,
    make_engine,
    open_historian,
    open_journal,
    stop_plant,
)
from hmi.codecache import dataclass_code, kept_codes, source_fingerprint

# The compiled scan's code (hmi.engine.codegen), kept beside hmi's bytecode as the dataclass
# methods' code is (hmi/codecache.py).
SCAN_CODE_PATH = (Path(__file__).resolve().parents[1] / "__pycache__"
                  / f"compiled-scan.{sys.implementation.cache_tag}.marshal")


def add_parser(sub) -> None:
    p = sub.add_parser("ui", help="open the operator HMI (the default command)")
    project_arg(p)
    diagnoser_arg(p)
    engine_args(p)
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="schedule a fault in the simulated plant")
    p.add_argument("--journal", type=Path, metavar="FILE",
                   help="journal file (default: the user's data folder, see plchmi journal)")
    journal_space_arg(p)
    p.add_argument("--bell", action="store_true",
                   help="ring the terminal bell when a new unacknowledged P1 alarm appears")
    plant_args(p, "keep trying")
    historian_args(p, "a SQLite file in the data folder, beside the journal")
    from hmi.opcua.options import add_arguments as opcua_args
    opcua_args(p)


def cmd_ui(args: argparse.Namespace) -> int:
    # The start (docs/performance.md): no garbage collection until the scans start (the
    # start allocates much and frees little; hmi.ui.driver.LiveDriver.start collects once,
    # freezes what exists and turns it back on), and the code of the generated dataclass
    # methods and of the compiled scan read from their caches instead of compiled again
    # (hmi/codecache.py), the project read back as loaded before (hmi/project/kept.py).
    gc.disable()
    try:
        with dataclass_code():
            import hmi.ui.app  # noqa: F401  (the HMI's modules: their classes built here)
            from hmi.engine import codegen
            from hmi.opcua.options import check_arguments
            from hmi.project import kept
            from hmi.session.session import Session
            check_arguments(args)
            # the project as an earlier start loaded it, if nothing it depends on changed
            project = kept.load(args.project, getattr(args, "diagnoser", None))
            with kept_codes(codegen.code_table(), SCAN_CODE_PATH, source_fingerprint(codegen)):
                engine, injections = make_engine(project, args)
            clock = None
            if engine.plant.is_real:
                from hmi.session.live import WallClock
                clock = WallClock()
            controller = Session(engine, clock=clock)
        return _run_hmi(args, controller, injections)
    finally:
        gc.enable()


def _run_hmi(args: argparse.Namespace, controller, injections) -> int:
    """The HMI on its session: the journal, the OPC UA server if asked, the plant's
    connection; whatever ends it, the journal says how (and a real plant is left safe)."""
    from hmi.opcua.options import start_server
    from hmi.ui.app import run_app
    from hmi.ui.csscache import kept_css
    engine = controller.engine
    project = engine.project
    clock = controller.clock
    recorder = None
    historian = None
    end = None
    server = None
    try:
        recorder = open_journal(controller, args.journal, "hmi")
        recorder.space(args.journal_space)
        historian = open_historian(controller, args, recorder, "hmi", default_on=True)
        server = start_server(controller, args, log_file=True, journal=recorder,
                              history=historian.target if historian else None)
        announce(server, project.name)
        if clock is not None:
            connect_plant(engine, args.connect_timeout)
        with kept_css() as css:  # Textual's stylesheets as parsed at an earlier start
            end = run_app(controller, injected=tuple(injections),
                          on_fault=recorder.on_ui_fault, bell=getattr(args, "bell", False),
                          served=server, on_first_frame=css.save if css else None)
        if end.reason is not None:
            print(f"plchmi: the HMI ended on an error: {end.reason}", file=sys.stderr)
        return end.status
    finally:
        if server is not None:
            server.stop()
        # a real plant: the safe outputs first, then the journal says how it ended
        if clock is not None:
            stop_plant(engine)
        if recorder is not None:
            if end is not None:
                recorder.close(end.reason, end.note)
            else:
                recorder.close(ended_by(sys.exc_info()[1]))
        if historian is not None:  # after the journal's last entry, which it keeps too
            historian.close()
