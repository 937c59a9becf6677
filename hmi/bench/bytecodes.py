"""Where a scan's instructions go: the bytecodes each function executes per scan.

``python -m hmi.bench.instructions`` counts a scan's machine instructions, all parts together;
this counts, with an opcode tracer (``sys.settrace``, ``f_trace_opcodes``), the bytecodes
every Python function executes while ``plchmi run P`` without trace runs (the bench's
``session_rate`` loop: session, engine, simulated plant), between two virtual times, per
scan. Like the instructions, the count does not depend on the load; it is exact for one
tree and fast (seconds, no valgrind). A scan's instructions are about 40 per bytecode on
CPython 3.11 (its eval loop is half of them; calls, attribute and item lookups most of the
rest), so the split says where to look; the instructions bench says what a change gained.

    python -m hmi.bench.bytecodes [--from 10] [--to 70] [--top 25] [PROJECT ...]

Functions are named by module (under hmi/) and name; the scan program's printed functions
by their label (``<plchmi compiled core: sorting/normal>:core``).
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable
from types import FrameType
from typing import Any

from hmi.bench.engine import PROJECTS
from hmi.bench.instructions import window_parser


def bytecodes(project: str, start: int, end: int) -> tuple[int, Counter[str]]:
    """(scans, bytecodes by function) of `project`'s run from `start` to `end` seconds of
    virtual time (the run up to `start` is not counted: the start and its first scans)."""
    from hmi.engine.build import build_engine
    from hmi.project.loader import load_project
    from hmi.session.run_report import RunCollector
    from hmi.session.session import Session

    loaded = load_project(PROJECTS / project)
    session = Session(build_engine(loaded))
    collector = RunCollector()
    collector.finish(session.run_for(start * 1_000_000, collector.add, collector.quiet))
    before = collector.scans
    counts: Counter[str] = Counter()

    def tracer(frame: FrameType, event: str, arg: Any) -> Callable[..., Any]:
        frame.f_trace_opcodes = True
        frame.f_trace_lines = False
        code = frame.f_code
        key = f"{code.co_filename.split('/hmi/')[-1]}:{code.co_name}"

        def opcodes(frame: FrameType, event: str, arg: Any) -> Callable[..., Any]:
            if event == "opcode":
                counts[key] += 1
            return opcodes
        return opcodes

    sys.settrace(tracer)
    try:
        collector.finish(session.run_for((end - start) * 1_000_000, collector.add,
                                         collector.quiet))
    finally:
        sys.settrace(None)
    return collector.scans - before, counts


def main(argv: list[str] | None = None) -> int:
    parser = window_parser("python -m hmi.bench.bytecodes", __doc__ or "",
                           (10, "seconds of virtual time before counting"),
                           (70, "seconds of virtual time where counting stops"))
    parser.add_argument("--top", type=int, default=25, help="functions listed (default 25)")
    args = parser.parse_args(argv)
    if args.end <= args.start:
        parser.error("--to must be after --from")
    for name in args.projects:
        scans, counts = bytecodes(name, args.start, args.end)
        total = sum(counts.values())
        print(f"  {name}: {total / scans:,.0f} bytecodes/scan over {scans:,} scans "
              f"({args.start} s to {args.end} s of virtual time)")
        for function, count in counts.most_common(args.top):
            print(f"  {count / scans:>9.1f}  {function}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
