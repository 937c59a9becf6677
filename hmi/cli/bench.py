"""``plchmi bench [SECTION...]``: measure and print performance figures (docs/performance.md);
the sections themselves are in hmi/bench/."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from hmi.errors import UsageError

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("bench", help="measure and print performance figures (never fails)")
    p.add_argument("sections", nargs="*", metavar="SECTION",
                   help="sections to run (default: all): " + ", ".join(_bench_sections()))
    p.add_argument("--quick", action="store_true", help="fewer samples, for a fast look")
    p.add_argument("--seed", type=int, default=1, help="random seed for generated problems")
    p.add_argument("--minutes", type=float, metavar="M",
                   help="live only: minutes measured per set-up (default 2; --quick: 1/3)")
    p.add_argument("--warm-minutes", type=float, metavar="M",
                   help="live only: minutes of warm-up before measuring (default 1/6)")
    p.add_argument("--screens", type=int, default=2, metavar="N",
                   help="live only: screens attached to the runtime, one of them opening "
                   "and closing dialogs (default 2)")
    p.add_argument("--dialog-every", type=float, default=0.5, metavar="S",
                   help="live only: a dialog opened and closed every S seconds (default 0.5)")
    p.add_argument("--no-realtime", action="store_true",
                   help="live only: the runtime at normal priority (plchmi serve "
                   "--no-realtime), e.g. beside another real-time measurement")
    p.add_argument("--split-only", action="store_true",
                   help="live only: the runtime and its screens alone (no one-process "
                   "comparison, no OPC UA attack)")
    p.add_argument("--against", metavar="DIR",
                   help="startup only: launch this checkout and the plchmi checkout in DIR "
                   "in turn, and compare them (before/after figures measured interleaved)")


def _bench_sections() -> list[str]:
    from hmi.bench import NAMES
    return list(NAMES)


def cmd_bench(args: argparse.Namespace) -> int:
    from hmi.bench import sections
    available = sections()
    chosen = args.sections or list(available)
    unknown = [s for s in chosen if s not in available]
    if unknown:
        raise UsageError(f"unknown bench section {', '.join(unknown)}; sections: "
                         + ", ".join(available))
    for index, name in enumerate(chosen):
        if index:
            print()
        print(f"== bench {name}: {available[name].HELP}", flush=True)
        available[name].run(args)
    return 0
