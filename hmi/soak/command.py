"""``plchmi soak PROJECT``: the command line of the soak, and what it prints.

    plchmi soak projects/cispi_valve --control faulty --minutes 30 --seed 7 --size 80x24

On success (exit 0) it prints the figures of the session: virtual time, scans, steps and what
they were, commands, alarms, journal lines. On a broken invariant (exit 1) it prints the seed,
the invariant and the step list that reproduces it — shrunk within ``--shrink`` seconds —
and saves that list so that ``--replay FILE`` runs it again.
"""

from __future__ import annotations

import argparse
import asyncio
from datetime import UTC, datetime
from pathlib import Path

from hmi.errors import UsageError
from hmi.limits import MAX_FILE_BYTES, MAX_RUN_SCANS
from hmi.project.loader import load_project
from hmi.soak.runner import ShrinkStopped, SoakConfig, SoakResult, session, shrink
from hmi.soak.steps import Step, StepError, format_steps, parse_steps, steps_header
from hmi.textfile import FileProblem, read_text
from hmi.timefmt import format_duration


def read_replay(path: Path, period_us: int) -> list[Step]:
    """The steps of a replay file, read as every file from outside is (a regular file of
    at most MAX_FILE_BYTES, strict UTF-8: hmi.textfile), their virtual time in all at most
    MAX_RUN_SCANS scans of `period_us`. Anything else is a usage error at the file's line and
    column."""
    try:
        text = read_text(path, MAX_FILE_BYTES)
    except FileProblem as exc:
        where = f"{path}:{exc.line}:{exc.col}" if exc.line else str(path)
        expected = f" (expected {exc.expected})" if exc.expected else ""
        raise UsageError(f"--replay {where}: {exc.message}{expected}") from None
    try:
        return parse_steps(text, str(path), period_us)
    except StepError as exc:
        raise UsageError(f"--replay {exc}") from None


def cmd_soak(args: argparse.Namespace) -> int:
    project = load_project(args.project)  # a bad project: its errors, exit 2
    if args.control and args.control not in project.controls:
        raise UsageError(f"--control {args.control!r}: the project has "
                         + ", ".join(project.controls))
    period = project.scan_period_us
    replay = None
    if args.replay is not None:
        replay = read_replay(args.replay, period)
    elif int(args.minutes * 60_000_000) // period + 1 > MAX_RUN_SCANS:
        raise UsageError(f"--minutes {args.minutes:g}: at a {format_duration(period)} scan "
                         f"period that is {int(args.minutes * 60_000_000) // period + 1:,} "
                         f"scans, more than the {MAX_RUN_SCANS:,} plchmi runs at once")
    if args.steps is not None and args.steps < 1:
        raise UsageError("--steps: at least 1")
    config = SoakConfig(Path(args.project), args.control, args.size, args.minutes, args.seed,
                        args.steps, split=getattr(args, "split", False))
    print(f"soak {project.name} (control {args.control or 'default'}, "
          f"{config.size[0]}x{config.size[1]}, seed {config.seed}): "
          + (f"replaying {len(replay)} steps" if replay is not None
             else f"{args.minutes:g} virtual minutes"), flush=True)
    result = asyncio.run(session(config, replay, progress=Progress()))
    print(summary(result))
    if result.ok:
        return 0
    broken = result.broken[0]
    print(f"\nBROKEN: {broken}")
    print(f"seed {config.seed}, after {len(result.steps)} steps; journal: {result.journal}")
    steps = result.steps
    if args.shrink > 0 and len(steps) > 1:
        print(f"shrinking the step list (up to {args.shrink:g} s)…", flush=True)
        try:
            steps, replays = asyncio.run(shrink(config, steps, broken.invariant, args.shrink))
        except ShrinkStopped as stop:
            steps, replays = stop.best, stop.replays
            print(f"the shrink stopped: {stop}")
        print(f"shrunk from {len(result.steps)} to {len(steps)} steps in {replays} replays")
    saved = save_steps(config, steps, str(broken))
    print(f"\nSteps that reproduce it (saved in {saved}):")
    print(format_steps(steps), end="")
    print(f"\nReplay: plchmi soak {args.project}"
          + (f" --control {args.control}" if args.control else "")
          + f" --size {config.size[0]}x{config.size[1]} --replay {saved}")
    return 1


class Progress:
    """A line every 5 virtual minutes: a long soak shows it is alive, and how fast it goes."""

    EVERY_US = 300_000_000

    def __init__(self) -> None:
        self.next_us = self.EVERY_US

    def __call__(self, result: SoakResult) -> None:
        if result.virtual_us < self.next_us:
            return
        self.next_us = result.virtual_us - result.virtual_us % self.EVERY_US + self.EVERY_US
        print(f"  … {result.virtual_us / 60e6:.1f} virtual minutes, {len(result.steps)} steps, "
              f"{result.scans} scans, {result.wall_s:.0f} s wall, "
              f"{len(result.broken)} broken", flush=True)


def save_steps(config: SoakConfig, steps: list[Step], why: str) -> Path:
    from hmi.paths import data_folder
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    path = data_folder() / "soak" / f"{config.project.name}-seed{config.seed}-{stamp}.steps"
    path.parent.mkdir(parents=True, exist_ok=True)
    head = steps_header(config.project, config.control, config.size, config.seed, why,
                        split=config.split)
    path.write_text(head + format_steps(steps), encoding="utf-8")
    return path


def summary(result: SoakResult) -> str:
    g = result.gestures
    answers = sum(n for k, n in g.items() if k.startswith("answer"))
    c = result.commands
    k = result.checks
    lines = [
        f"  {format_duration(result.virtual_us - result.virtual_us % 1000)} virtual in "
        f"{len(result.steps)} steps, {result.scans} scans, {result.wall_s:.1f} s wall",
        f"  steps: run {g['run']}, keys {g['press']}, palette {g['palette']}, "
        f"I/O rows {g['row']}, clicks {g['click']}, resizes {g['resize']}, dialog answers "
        f"{answers}" + (f"; {result.skipped} not possible" if result.skipped else ""),
        "  commands accepted: " + (", ".join(f"{k} {n}" for k, n in sorted(c.items()))
                                   or "none") + f"; refused {result.refused}",
        *(["  refused most: " + "; ".join(f"{why} ({n})" for why, n
                                          in result.refusals.most_common(3))]
          if result.refusals else []),
        f"  alarms: {result.raised} raised, {result.transitions} state changes (all in the "
        f"journal), at most {result.max_alarms} listed; journal {result.journal_lines} lines",
        f"  invariants: {len(result.broken)} broken; checked: {k['step']} times after a step "
        f"(app alive, status bar, journal), {k['constraint']} constraint evaluations on the "
        f"outputs written, {k['alarm']} alarm-row comparisons, {result.journal_lines} journal "
        "lines parsed",
    ]
    if result.safe_state_violations:
        lines.insert(-1, "  safe state written by decision, leaving constraints violated "
                     "(allowed: the safe state has the last word): " + ", ".join(
                         f"{name} {n} scans" for name, n in
                         sorted(result.safe_state_violations.items())))
    return "\n".join(lines)
