"""What the commands that drive a session (run, ui) share: the engine their options ask
for, the real plant's connection and stop, the OPC UA announcement, the journal."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure
from hmi.errors import UsageError
from hmi.timefmt import format_duration

if TYPE_CHECKING:
    from hmi.engine.scan import Engine
    from hmi.history.historian import Historian
    from hmi.opcua.server import CellServer
    from hmi.project.injection import Injection
    from hmi.project.model import Project
    from hmi.session.journal_recorder import JournalRecorder
    from hmi.session.session import Session


def make_engine(project: Project, args: argparse.Namespace,
                extra_injections: Iterable[Injection] = ()) -> tuple[Engine, list[Injection]]:
    """The engine for a command's --control/--policy/--inject/--plant options."""
    from hmi.engine.build import EngineOptions, build_engine
    from hmi.plant.select import open_plant
    from hmi.project.injection import parse_injection

    if args.control and args.control not in project.controls:
        raise UsageError(f"--control {args.control!r}: the project has "
                         + ", ".join(project.controls))
    injections = [*extra_injections,
                  *(parse_injection(text) for text in getattr(args, "inject", []))]
    read_only = getattr(args, "read_only", False)
    plant = open_plant(project, getattr(args, "plant", None), read_only, injections,
                       getattr(args, "period", None))
    # The engine refuses the monitor policy on a real plant unless --allow-monitor.
    engine = build_engine(project, plant, EngineOptions(
        control=args.control, policy=args.policy, solver=args.solver,
        diagnosis=getattr(args, "diagnosis", None) or "ftc",
        solver_budget=getattr(args, "solver_budget", None),
        allow_monitor_policy=getattr(args, "allow_monitor", False)))
    return engine, injections


def connect_plant(engine: Engine, timeout_us: int | None) -> None:
    """Connect a real plant before the first scan, saying what happens; exit 1 if it fails."""
    plant = engine.plant
    if not plant.is_real:
        return
    from hmi.plant.modbus.client import ModbusPlant, wait_connected
    assert isinstance(plant, ModbusPlant)  # the one real plant

    def report(line: str) -> None:
        print(f"plchmi: {line}", file=sys.stderr, flush=True)
    timeout_s = None if timeout_us is None else timeout_us / 1e6
    if not wait_connected(plant, timeout_s, report):
        plant.close()
        waited = "the wait" if timeout_us is None else format_duration(timeout_us)
        raise RunFailure(f"no connection to the plant within {waited}: {plant.message}")


def announce(server: CellServer | None, name: str) -> None:
    """Say where the cell is served (on stderr: a served run's stdout is its summary)."""
    if server is not None:
        print(f"plchmi: serving {name} over OPC UA at {server.url}"
              + (" (operator commands enabled)" if server.options.writable else ""),
              file=sys.stderr, flush=True)


def stop_plant(engine: Engine) -> None:
    """At the end of a run on a real plant, leave its outputs safe, as a stopping PLC does."""
    safe = dict(zip(engine.layout.outputs, engine.safe_vector, strict=True))
    engine.plant.stop(engine.now, safe)


def open_journal(session: Session, path: Path | None, source: str) -> JournalRecorder:
    from hmi.session.runio import open_journal as open_recorder
    return open_recorder(session, path, source)


def open_historian(session: Session, args: argparse.Namespace, journal: JournalRecorder | None,
                   source: str, default_on: bool, run_us: int | None = None
                   ) -> Historian | None:
    """The cell's historian (hmi.history), attached, or None: `--historian off`, or a
    headless run in virtual time that did not ask for one (`default_on` False: its hours
    of simulated time would sit in the cell's history as if they had happened; asked for,
    it is placed to end when the run ends, `run_us` after its start)."""
    from hmi.history.target import default_target, parse_target
    text = getattr(args, "historian", None)
    if text == "off" or (text is None and not default_on):
        return None
    try:
        target = parse_target(text) if text else default_target(session.project.name)
    except ValueError as exc:
        raise UsageError(f"--historian: {exc}") from None
    if target.kind == "postgresql":
        try:
            import psycopg  # noqa: F401
        except ImportError:
            from hmi.history.postgres import NEEDS_EXTRA
            raise UsageError(f"--historian {target.describe()}: {NEEDS_EXTRA}") from None
    from hmi.history.historian import Historian
    from hmi.history.writer import DEFAULT_RETENTION_US
    retention = getattr(args, "history_retention", None) or DEFAULT_RETENTION_US
    return Historian(session, target, source=source, journal=journal,
                     retention_us=retention, run_us=run_us).attach()
