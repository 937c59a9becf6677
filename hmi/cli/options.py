"""What several commands' options share: the argument types (a duration, a scan period, a
port...) and the groups of options (project, diagnoser variant, engine, plant).

A bad value is an `argparse.ArgumentTypeError` with a message saying what was expected, so
that argparse reports it with exit status 2 and no traceback.
"""

from __future__ import annotations

import argparse

from hmi.limits import MIN_SCAN_PERIOD_US
from hmi.timefmt import DURATION_HINT, DurationError, format_duration, parse_duration


def duration(text: str) -> int:
    try:
        us = parse_duration(text)
    except DurationError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} {exc.reason} (expected {DURATION_HINT})"
                                         ) from None
    if us <= 0:
        raise argparse.ArgumentTypeError("the duration must be longer than zero")
    return us


def period(text: str) -> int:
    us = duration(text)
    if us < MIN_SCAN_PERIOD_US:
        raise argparse.ArgumentTypeError(f"{text!r} is shorter than the shortest scan period "
                                         f"({format_duration(MIN_SCAN_PERIOD_US)})")
    return us


def solver_budget(text: str) -> int:
    from hmi.project.model import MAX_SOLVER_BUDGET, MIN_SOLVER_BUDGET
    try:
        if not text.isascii():  # "１０００" is int() 1000: digits a reader would not see
            raise ValueError(text)
        value = int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of steps") from None
    if not MIN_SOLVER_BUDGET <= value <= MAX_SOLVER_BUDGET:
        raise argparse.ArgumentTypeError(
            f"{value} steps is out of range: between {MIN_SOLVER_BUDGET:,} and "
            f"{MAX_SOLVER_BUDGET:,}")
    return value


def whole(text: str, most: int) -> int | None:
    """`text` as a whole number from 0 to `most`, ASCII digits only ("²".isdigit() is true)."""
    if not (text.isascii() and text.isdigit()) or len(text) > 6 or int(text) > most:
        return None
    return int(text)


def tcp_port(text: str) -> int:
    port = whole(text, 65535)
    if port is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (0 to 65535)")
    return port


def unit_id(text: str) -> int:
    unit = whole(text, 255)
    if unit is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a Modbus unit id (0 to 255)")
    return unit


def positive(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 10_000:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number from 1 to 10000")
    return int(text)


_SIZE_UNITS = {"B": 1, "kB": 1000, "KB": 1000, "MB": 1000**2, "GB": 1000**3, "TB": 1000**4,
               "KiB": 1024, "MiB": 1024**2, "GiB": 1024**3, "TiB": 1024**4}


def size_bytes(text: str) -> int:
    """A size such as 500MB, 2GB or 1GiB, in bytes."""
    import re
    match = re.fullmatch(r"([0-9]{1,9}(?:\.[0-9]{1,3})?)\s*([kKMGT]i?B|B)", text.strip())
    if match is None or match[2] not in _SIZE_UNITS:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size (expected e.g. 500MB, 2GB "
                                         "or 1GiB)")
    whole, _, frac = match[1].partition(".")
    scale = _SIZE_UNITS[match[2]]
    value = int(whole) * scale + (int(frac) * scale // 10 ** len(frac) if frac else 0)
    if value < 1_000_000:
        raise argparse.ArgumentTypeError(f"{text!r}: at least 1MB")
    return value


def journal_space_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--journal-space", type=size_bytes, default=1 << 30, metavar="SIZE",
                   help="the space the journal may take (default 1GiB); an alarm at 80 %% "
                   "of it, or of what its disk has left if that is less")


def project_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("project", help="project folder (or its project.yaml)")


def diagnoser_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--diagnoser", metavar="VARIANT",
                   help="load this variant of the diagnosers (e.g. paper); default: "
                   "the first each declares")


def engine_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--control", metavar="VARIANT",
                   help="control law variant to run (default: the project's first)")
    p.add_argument("--policy", choices=("monitor", "block", "correct"),
                   help="safety filter policy (default: the project's)")
    p.add_argument("--solver", choices=("exact", "paper"),
                   help="corrector search strategy (default: the project's, else exact)")
    p.add_argument("--solver-budget", type=solver_budget, metavar="STEPS",
                   help="corrector search budget per scan, in steps; past it the safe "
                   "state is written (default: the project's, else half the scan period "
                   "in microseconds)")


def plant_args(p: argparse.ArgumentParser, connect_default: str) -> None:
    p.add_argument("--plant", metavar="PLANT",
                   help="sim, modbus (the project's settings) or "
                   "modbus://HOST:PORT[/UNIT] (default: the project's plant)")
    p.add_argument("--read-only", action="store_true",
                   help="observe a real PLC over Modbus: read its inputs and outputs, "
                   "check the constraints on them, write nothing")
    p.add_argument("--connect-timeout", type=duration, metavar="TIME",
                   help="give up if a Modbus plant does not answer within TIME "
                   f"(default: {connect_default})")
    p.add_argument("--allow-monitor", action="store_true",
                   help="permit the monitor policy (unsafe orders pass) on a real plant")


def history_length(text: str) -> int:
    from hmi.history.span import SpanError, parse_span
    try:
        return parse_span(text)
    except SpanError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def historian_args(p: argparse.ArgumentParser, default: str) -> None:
    """Where the cell's history is kept (docs/history.md)."""
    p.add_argument("--historian", metavar="TARGET",
                   help="keep the cell's history in TARGET: a SQLite file, a "
                   "postgresql://USER@HOST/DB URL (needs the postgres extra), or off "
                   f"(default: {default})")
    p.add_argument("--history-retention", type=history_length, metavar="LENGTH",
                   help="delete history older than this, e.g. 30d (default: 90d)")
