"""What the study commands share to run on this machine or a Dask cluster: ``--jobs``,
``--cluster``, ``--resume``; the progress line; and, after the report, its hash and how the
study ran — on stderr, since the report itself is the same whatever ran it."""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure

if TYPE_CHECKING:
    from hmi.farm.run import Farm, Progress, Tick


def add_farm_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="local worker processes (default: 2 if the machine has 2 cores or "
                   "more; 1: this process)")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="run the shards on a Dask cluster: tcp://HOST:PORT (its scheduler; "
                   "every worker must run this plchmi) or local:N (N worker processes "
                   "here); needs pip install 'plchmi[cluster]' (docs/studies.md)")
    p.add_argument("--resume", nargs="?", const="", default=None, metavar="DIR",
                   help="reuse the shards an interrupted or earlier run of the same study "
                   "kept (same project, code and options), in the data folder or in DIR; "
                   "every run keeps its shards there")


@contextmanager
def farm_of(args: argparse.Namespace) -> Iterator[Farm]:
    """The farm the options say, its executor entered (a cluster connected, its workers'
    versions checked) for the command's length; Ctrl-C says what was kept."""
    from hmi.farm.executors import FarmError, executor_for
    from hmi.farm.run import Farm, Interrupted

    executor = executor_for(args.cluster, args.jobs)
    root = Path(args.resume) if args.resume else None
    farm = Farm(executor, progress_line(), resume=args.resume is not None, root=root)
    try:
        with executor:
            yield farm
    except Interrupted as exc:
        where = f"; kept in {exc.folder}" if exc.folder else ""
        again = f" --resume {args.resume}" if args.resume else " --resume"
        print(f"\ninterrupted: {exc.done} of {exc.shards} shards done{where}; the same "
              f"command with{again} goes on from there", file=sys.stderr, flush=True)
        raise KeyboardInterrupt from None
    except FarmError as exc:
        raise RunFailure(f"the study stopped: {exc}") from None


def print_report(text: str, farm: Farm) -> None:
    """The report on stdout; its sha256 and how the study ran on stderr."""
    data = text if text.endswith("\n") else text + "\n"
    sys.stdout.write(data)
    sys.stdout.flush()
    digest = hashlib.sha256(data.encode("utf-8")).hexdigest()
    print(f"report sha256 {digest}", file=sys.stderr)
    for note in farm.notes:
        print(f"  {note}", file=sys.stderr)
    for stats in farm.stats:
        for line in stats.lines():
            print(f"  {line}", file=sys.stderr)
    sys.stderr.flush()


def progress_line() -> Progress:
    """One line on stderr, rewritten after each shard: shards and runs done, runs per
    second, time left; what happens on the way (a worker lost) on a line of its own. When
    stderr is a file, not a terminal, a line at each tenth of the runs instead."""
    shown = [-1.0]
    tenth = [-1]
    terminal = sys.stderr.isatty()

    def progress(tick: Tick) -> None:
        if tick.note:
            print(f"\n{tick.note}" if shown[0] >= 0 and terminal else tick.note,
                  file=sys.stderr, flush=True)
        now = time.monotonic()
        last = tick.shards_done >= tick.shards
        percent = 100 * tick.runs_done // max(1, tick.runs)
        if not terminal:
            if percent // 10 == tenth[0] and not last:
                return
            tenth[0] = percent // 10
        elif not last and now - shown[0] < 0.25 and not tick.note:
            return
        shown[0] = now
        bar = "#" * (percent // 4)
        eta = "" if tick.eta_s is None or last else f"  about {_minutes(tick.eta_s)} left"
        start = "\r" if terminal else ""
        print(f"{start}[{bar:<25}] {percent:3d}%  {tick.shards_done}/"
              f"{tick.shards} shards  {tick.runs_done:,}/{tick.runs:,} runs  "
              f"{tick.rate:,.1f} runs/s  {tick.elapsed_s:5.1f} s{eta}   ",
              end="\n" if last or not terminal else "", file=sys.stderr, flush=True)

    return progress


def _minutes(s: float) -> str:
    whole = max(1, round(s))
    return f"{whole // 60} min {whole % 60:02d} s" if whole >= 60 else f"{whole} s"
