"""Instructions per scan of `plchmi run P` without trace, under valgrind's callgrind.

Why instructions: on the shared virtual machine the CPU's own speed moves by a third between
two runs of one command (docs/performance.md), so scans per second cannot tell a change of
a few per cent from the noise; the number of instructions a scan executes does not depend on
the load. Each project is run twice, in a fresh interpreter under callgrind, by the bench's
own ``session_rate`` (what ``plchmi run P --for S`` does without ``--trace``: the goal's
figure): once for FROM seconds of virtual time and once for TO seconds. The difference of
the two totals over the difference of the scans is the cost of a scan, the start (imports,
project, engine) cancelling out. With FROM 0 (the default) it is the average over the whole
run, first scans included; ``--from 60`` gives the steady state.

    python -m hmi.bench.instructions [--from 0] [--to 120] [PROJECT ...]

Slow (callgrind runs Python some 50 times slower): about a minute per project and run.
``PYTHONHASHSEED`` is fixed so that two runs execute the very same instructions.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from hmi.bench.engine import GOALS, PROJECTS

# What the child runs: the bench's session figure for SPAN seconds, printing the scans (a run
# of 0 s is one scan: the engine built, its code generated, the modules of a scan imported).
_CHILD = ("import sys; from hmi.bench.engine import session_rate; "
          "from hmi.project.loader import load_project; "
          "p = load_project(sys.argv[1]); "
          "print(session_rate(p, int(sys.argv[2]) * 1_000_000)[0])")
_TOTAL = re.compile(r"^(?:summary|totals): (\d+)", re.MULTILINE)


def instructions(project: Path, seconds: int) -> tuple[int, int]:
    """(scans, instructions) of one run of `seconds` under callgrind, interpreter included."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        env = dict(os.environ, PYTHONHASHSEED="0")
        done = subprocess.run(
            ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
             sys.executable, "-c", _CHILD, str(project), str(seconds)],
            capture_output=True, text=True, env=env, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"callgrind run failed ({done.returncode}):\n{done.stderr}")
        found = _TOTAL.search(out.read_text())
        if found is None:
            raise RuntimeError(f"no total in {out}")
        return int(done.stdout.split()[-1]), int(found.group(1))


def per_scan(project: Path, start: int, end: int) -> tuple[int, float]:
    """(scans between the two runs, instructions per scan)."""
    scans_a, total_a = instructions(project, start)
    scans_b, total_b = instructions(project, end)
    scans = scans_b - scans_a
    return scans, (total_b - total_a) / scans


def window_parser(prog: str, doc: str, start: tuple[int, str], end: tuple[int, str]
                  ) -> argparse.ArgumentParser:
    """The command line of a count between two virtual times (this bench's, and
    hmi.bench.bytecodes'): projects, --from and --to, each (default, help)."""
    parser = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0])
    parser.add_argument("projects", nargs="*", default=list(GOALS))
    parser.add_argument("--from", dest="start", type=int, default=start[0],
                        help=f"{start[1]} (default {start[0]})")
    parser.add_argument("--to", dest="end", type=int, default=end[0],
                        help=f"{end[1]} (default {end[0]})")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = window_parser("python -m hmi.bench.instructions", __doc__ or "",
                           (0, "seconds of virtual time of the first run"),
                           (120, "seconds of virtual time of the second run"))
    args = parser.parse_args(argv)
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (apt-get install valgrind)", file=sys.stderr)
        return 2
    print(f"  instructions per scan, callgrind, runs of {args.start} s and {args.end} s of "
          "virtual time (plchmi run without trace)", flush=True)
    for name in args.projects:
        scans, cost = per_scan(PROJECTS / name, args.start, args.end)
        print(f"  {name:<16} {cost:>9,.0f} instructions/scan over {scans:,} scans", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
