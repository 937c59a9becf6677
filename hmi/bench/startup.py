"""``plchmi bench startup``: from launching ``plchmi PROJECT`` to its first useful frame.

The HMI is started as the operator starts it, a new process in a real (pseudo-)terminal of
80×24, and the clock stops when the terminal has received the first frame that holds the I/O
table with its rows (the column header and the first input's name), not when the imports are
done: the figure includes the interpreter, the imports, loading the project, building the
engine, the first scan, Textual's first layout and the bytes written. The app is then quit
(ctrl+q, confirmed) and reaped. One launch first, untimed, warms the caches (bytecode and the
dataclass methods' code written as on an operator's machine, files in the OS cache). Also
printed: the time to import the HMI's module alone (in a fresh interpreter, without the
start's caches), for comparison.

The goal: the first useful frame in under half a second on a quiet machine. The
machine's load average is printed beside the figures: on a shared machine they are noisy.
Beside the wall time, the CPU time the HMI's process had used when its first frame arrived
(from /proc, in clock ticks): on a quiet machine the two are close (the start is one
thread), on a loaded one the wall time grows with the load and the CPU time much less, so
it is the figure to compare between runs when no quiet machine is to be had.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from hmi.bench import load_line
from hmi.errors import UsageError

SECTION = "startup"
HELP = "launch -> first frame with the I/O table at 80x24 (goal < 0.5 s); import time"

GOAL_S = 0.5
ROOT = Path(__file__).resolve().parents[2]
PROJECT = ROOT / "projects" / "cispi_valve"
RUNS, QUICK_RUNS = 5, 3
SIZE = (80, 24)
TIMEOUT_S = 30.0
QUIT = b"\x11"  # ctrl+q
CONFIRM = b"y"  # the quit dialog's "Quit" (no binding of the main screen)
CONFIRM_EVERY_S = 0.25


@dataclass(frozen=True)
class Launch:
    """One launch: seconds from the fork to the first frame (None: none in time), and the
    CPU seconds the process had used by then (None where /proc cannot tell)."""

    wall_s: float | None
    cpu_s: float | None = None


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a live process, from /proc/PID/stat (Linux)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def first_frame(argv: list[str], markers: tuple[bytes, ...], env: dict[str, str],
                size: tuple[int, int] = SIZE, timeout_s: float = TIMEOUT_S,
                cwd: Path | None = None) -> Launch:
    """The time from the fork of `argv` in a new pseudo-terminal of `size` (columns, rows)
    until every marker has appeared in what it wrote (and the CPU time it had used then).
    The process is asked to quit, then killed if it does not, and always reaped."""
    import fcntl
    import pty
    import struct
    import termios

    started = time.perf_counter()
    pid, fd = pty.fork()
    if pid == 0:  # the child: the HMI, in the new terminal
        try:
            if cwd is not None:  # `python -m hmi.cli` imports the hmi of its folder
                os.chdir(cwd)
            os.execve(argv[0], argv, env)
        finally:
            os._exit(127)
    cols, rows = size
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))
    seen = Launch(None)
    received = b""
    try:
        while time.perf_counter() - started < timeout_s:
            ready, _, _ = select.select([fd], [], [], 0.05)
            if not ready:
                continue
            try:
                chunk = os.read(fd, 1 << 16)
            except OSError:  # the child closed the terminal
                break
            if not chunk:
                break
            received += chunk
            if all(m in received for m in markers):
                seen = Launch(time.perf_counter() - started, cpu_seconds(pid))
                break
        _quit(pid, fd)
    finally:
        os.close(fd)
    return seen


def _quit(pid: int, fd: int) -> None:
    """Ask the app to quit (ctrl+q, then confirm until it has: its dialog comes up when the
    app gets to it), drain its output, kill it after 5 s; reap it."""
    with contextlib.suppress(OSError):
        os.write(fd, QUIT)
    deadline = time.perf_counter() + 5.0
    confirm = time.perf_counter() + CONFIRM_EVERY_S
    while time.perf_counter() < deadline:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done:
            return
        if time.perf_counter() >= confirm:
            with contextlib.suppress(OSError):
                os.write(fd, CONFIRM)
            confirm += CONFIRM_EVERY_S
        ready, _, _ = select.select([fd], [], [], 0.05)
        if ready:
            with contextlib.suppress(OSError):
                os.read(fd, 1 << 16)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)


def import_seconds(module: str) -> float:
    """Wall time of a fresh interpreter importing `module` (interpreter start included),
    with the bytecode cache in use."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True, env=env)
    return time.perf_counter() - started


@dataclass(frozen=True)
class Checkout:
    """A plchmi source tree whose HMI a launch starts (this one, or --against another)."""

    label: str
    root: Path

    def argv(self) -> list[str]:
        return [sys.executable, "-m", "hmi.cli", str(self.root / "projects" / PROJECT.name)]


def checkouts(against: str | None) -> list[Checkout]:
    """This checkout, and the one to compare with (bench startup --against DIR)."""
    found = [Checkout("this checkout", ROOT)]
    if against:
        other = Path(against).resolve()
        if not ((other / "hmi" / "ui" / "app.py").is_file()
                and (other / "projects" / PROJECT.name).is_dir()):
            raise UsageError(f"--against {against}: not a plchmi checkout (no hmi/ui/app.py "
                             f"or projects/{PROJECT.name} there)")
        found.append(Checkout(f"--against {against}", other))
    return found


def run(args: argparse.Namespace) -> None:
    from hmi.project.loader import load_project

    runs = QUICK_RUNS if getattr(args, "quick", False) else RUNS
    trees = checkouts(getattr(args, "against", None))
    project = load_project(PROJECT)
    markers = (b"Signal", project.inputs[0].name.encode())
    launches: dict[Checkout, list[Launch]] = {tree: [] for tree in trees}
    with tempfile.TemporaryDirectory() as data:
        env = dict(os.environ, TERM="xterm-256color", PLCHMI_DATA=data,
                   COLUMNS=str(SIZE[0]), LINES=str(SIZE[1]))
        # As on an operator's machine: the bytecode cache written (a launch compiling every
        # module is not the usual start; a development shell may forbid writing it).
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        print(f"  plchmi projects/{PROJECT.name} in a {SIZE[0]}x{SIZE[1]} pseudo-terminal, "
              f"{runs} launches" + (" each, interleaved," if len(trees) > 1 else "")
              + f" after one to warm the caches; {load_line()}", flush=True)
        for tree in trees:
            first_frame(tree.argv(), markers, env, cwd=tree.root)
        for _ in range(runs):
            for tree in trees:
                launches[tree].append(first_frame(tree.argv(), markers, env, cwd=tree.root))
    for tree in trees:
        if len(trees) > 1:
            print(f"  {tree.label} ({tree.root}):")
        _report(launches[tree])
    if len(trees) > 1:
        _compare(*(launches[tree] for tree in trees))
    print(f"  {load_line()}")
    imports = [import_seconds("hmi.ui.app") for _ in range(runs)]
    print(f"  import hmi.ui.app alone (fresh interpreter): median "
          f"{statistics.median(imports):.2f} s; interpreter alone: "
          f"{statistics.median([import_seconds('sys') for _ in range(runs)]):.2f} s")


def _report(launches: list[Launch]) -> None:
    got = [launch.wall_s for launch in launches if launch.wall_s is not None]
    shown = "  ".join("timeout" if launch.wall_s is None else f"{launch.wall_s:.2f}"
                      for launch in launches)
    if not got:
        print(f"  no first frame within {TIMEOUT_S:.0f} s ({shown})")
        return
    median = statistics.median(got)
    print(f"  first frame with the I/O table: median {median:.2f} s, min {min(got):.2f} s, "
          f"max {max(got):.2f} s  ({shown})")
    cpu = [launch.cpu_s for launch in launches if launch.cpu_s is not None]
    if cpu:
        print(f"  CPU time of the HMI's process at its first frame: median "
              f"{statistics.median(cpu):.2f} s, min {min(cpu):.2f} s")
    print(f"  goal < {GOAL_S} s: {'met' if median < GOAL_S else 'NOT met'} "
          f"(median {median / GOAL_S:.1f}x the goal)")


def _compare(these: list[Launch], others: list[Launch]) -> None:
    """Launch by launch (each pair started one after the other): how many times faster this
    checkout is than the other, in wall time and in CPU time."""
    for what, pairs in (("wall", [(a.wall_s, b.wall_s) for a, b in zip(these, others,
                                                                       strict=True)]),
                        ("CPU", [(a.cpu_s, b.cpu_s) for a, b in zip(these, others,
                                                                   strict=True)])):
        ratios = [b / a for a, b in pairs if a and b]
        if ratios:
            print(f"  this checkout is {statistics.median(ratios):.2f}x faster in {what} time "
                  f"(median of {len(ratios)} interleaved pairs)")
