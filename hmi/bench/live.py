"""``plchmi bench live``: a running cell with operators at its screens, the split against one
process per HMI, in real terminals.

Two HMIs at 80x24 on the CISPI valve (10 ms scan), each in a terminal of its own (tmux, on a
private server), one of them opening and closing the fault dialog and the command palette
in turn (a key every 0.25 s: a dialog opened and closed every 0.5 s), the other left alone:

- ``split``: one runtime (``plchmi serve``) and the two screens attached to it (``plchmi
  attach``), plus this bench's own viewer, which asks the runtime for its figures
  (``Query``): the scans, the overruns (a scan more than a period late), the lateness of
  each scan's start (p50, p99, max: measured inside the runtime), its memory;
- ``one process``: each HMI with its cell's scans in its own process, as before the split
  (:class:`~hmi.link.local.SessionLink`): each process writes its own figures.

Then ``OPC UA HEL attack``: the runtime with its OPC UA gateway (``plchmi gateway``) and one
client that sends a HEL claiming 2 GiB, then streams data into it for the whole window: the
runtime's scans and memory, the gateway's memory.

Memory is sampled every second after a warm-up (the screen opening its dialogs already);
its growth is per minute of the measured
window, and over its second half alone (what is left once the bounded caches have filled).
Attaching is timed too (connect to first frame). The machine is shared: its load is
printed beside the figures. ``--quick`` shortens each set-up; ``--minutes``, ``--screens``,
``--dialog-every`` and ``--split-only`` set up the issue's own goal (``--minutes 10
--screens 4 --dialog-every 0.25 --split-only``: one screen opening and closing a dialog every
quarter second, three more attached, ten minutes).
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from hmi.bench import load_line
from hmi.bench.ui import PERIOD_US, PROJECT

SECTION = "live"
HELP = ("HMIs at 80x24 on cispi_valve (10 ms scan), one opening and closing dialogs: scan "
        "overruns and memory, the runtime and its screens vs one process per HMI, and under "
        "an OPC UA HEL attack")

SECONDS, QUICK_SECONDS = 120.0, 20.0
WARM_S, QUICK_WARM_S = 10.0, 4.0  # after the screens started: not measured
SIZE = (80, 24)
KEYS = ("f", "Escape", "C-p", "Escape")  # the fault dialog, then the palette
DIALOG_EVERY_S = 0.5  # a key every half of it: open, then close
START_S = 120.0  # a hang guard only (a loaded machine starts slowly)


@dataclass(frozen=True)
class Setup:
    """How long, how many screens, how often a dialog."""

    seconds: float
    warm_s: float
    screens: int = 2
    dialog_every: float = DIALOG_EVERY_S
    realtime: bool = True  # the runtime's scan at SCHED_FIFO where the kernel allows it


@dataclass
class Sampled:
    """One process's memory, sampled every second (kB)."""

    pid: int
    rss_kb: list[int] = field(default_factory=list)

    def sample(self) -> None:
        self.rss_kb.append(rss_of(self.pid))

    def line(self, label: str, seconds: float) -> str:
        if not self.rss_kb:
            return f"  {label:<22} no memory sample"
        first, last = self.rss_kb[0], self.rss_kb[-1]
        growth = (last - first) / 1024
        half = (last - self.rss_kb[len(self.rss_kb) // 2]) / 1024
        return (f"  {label:<22} RSS {first / 1024:6.1f} -> {last / 1024:6.1f} MB "
                f"({growth:+.1f} MB in {seconds:.0f} s, {growth * 60 / seconds:+.2f} MB/min;"
                f" second half {half * 120 / seconds:+.2f} MB/min;"
                f" peak {max(self.rss_kb) / 1024:.1f} MB)")


def rss_of(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


class Terminals:
    """Real terminals: a private tmux server (its own socket), killed at the end."""

    def __init__(self) -> None:
        self.socket = f"plchmi-bench-live-{os.getpid()}"

    def tmux(self, *args: str) -> str:
        done = subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True,
                              text=True, check=True)
        return done.stdout.strip()

    def open(self, name: str, command: list[str], env: dict[str, str]) -> int:
        """A terminal of SIZE running `command`; the command's pid."""
        settings = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items())
        self.tmux("new-session", "-d", "-s", name, "-x", str(SIZE[0]), "-y", str(SIZE[1]),
                  f"exec env {settings} {shlex.join(command)}")
        self.tmux("set-option", "-t", name, "remain-on-exit", "on")  # (to say why it ended)
        return int(self.tmux("display-message", "-p", "-t", name, "#{pane_pid}"))

    def ended(self, name: str) -> str | None:
        """What a terminal whose program ended shows last (None while it runs)."""
        if self.tmux("display-message", "-p", "-t", name, "#{pane_dead}") != "1":
            return None
        lines = [line for line in self.screen(name).splitlines() if line.strip()]
        return " / ".join(lines[-3:]) or "(nothing)"

    def press(self, name: str, key: str) -> None:
        self.tmux("send-keys", "-t", name, key)

    def screen(self, name: str) -> str:
        return self.tmux("capture-pane", "-p", "-t", name)

    def close(self) -> None:
        subprocess.run(["tmux", "-L", self.socket, "kill-server"], capture_output=True)


def _wait(predicate, what: str) -> None:
    started = time.monotonic()
    while not predicate():
        if time.monotonic() - started > START_S:
            raise RuntimeError(f"{what} did not happen within {START_S:g} s")
        time.sleep(0.1)


def _drive(terminals: Terminals, name: str, seconds: float, samplers: list[Sampled],
           dialog_every: float) -> str | None:
    """Press the dialog keys in `name` (one every half of `dialog_every`) for `seconds`,
    sampling memory every second; stopped early if the screen ends (what it shows last is
    returned)."""
    start = time.monotonic()
    next_sample = start
    pressed = 0
    while (now := time.monotonic()) - start < seconds:
        if now >= next_sample:
            ended = terminals.ended(name)
            if ended is not None:
                return f"the screen with dialogs ENDED after {now - start:.0f} s: {ended}"
            for sampler in samplers:
                sampler.sample()
            next_sample += 1.0
        terminals.press(name, KEYS[pressed % len(KEYS)])
        pressed += 1
        time.sleep(dialog_every / 2)
    for sampler in samplers:
        sampler.sample()
    return None


def _started(terminals: Terminals, name: str) -> bool:
    return "Mode" in terminals.screen(name) or "AUTO" in terminals.screen(name)


# -- the split -------------------------------------------------------------------------------

class Runtime:
    """``plchmi serve`` on the bench's project, with this bench's viewer attached (its
    figures: Query), stopped at the end."""

    def __init__(self, folder: Path, env: dict[str, str], realtime: bool = True):
        from hmi.link.client import SocketLink
        from hmi.project.kept import fingerprint, load_once
        from hmi.wire import messages as m

        self.sock = folder / "runtime.sock"
        folder.mkdir(parents=True)
        self.log = open(folder / "runtime.log", "wb")  # noqa: SIM115 (closed by stop)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "hmi.cli", "serve", str(PROJECT), "--socket",
             str(self.sock), *([] if realtime else ["--no-realtime"])],
            stdin=subprocess.DEVNULL, stdout=self.log, stderr=self.log,
            env={**os.environ, **env})
        try:
            _wait(self.sock.exists, "the runtime's socket")
            project = load_once(PROJECT, None)
            started = time.perf_counter()
            self.viewer = SocketLink(project, self.sock, fingerprint(PROJECT, None),
                                     m.Identity("bench", "viewer", "cli", "bench"),
                                     want_control=False)
            self.viewer.first_frame.wait(START_S)
            self.first_frame_s = time.perf_counter() - started
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
        self.process.wait(START_S)
        self.log.close()

    def figures(self, before, after, elapsed: float, tally: dict[str, int], label: str
                ) -> list[str]:
        if before is None or after is None:
            return ["  the runtime did not answer the bench's queries"]
        tally[label] = after.overruns - before.overruns
        scans = after.scans - before.scans
        return [
            f"  {'runtime':<22} {scans} scans in {elapsed:.1f} s "
            f"({scans * PERIOD_US / 1e6 / elapsed:.1%} of real time), "
            f"{after.overruns - before.overruns} overruns; scan start lateness since start "
            f"p50 {after.jitter_p50_us:.0f} us, p99 {after.jitter_p99_us:.0f} us, "
            f"max {after.jitter_max_us / 1000:.1f} ms",
            f"  {'':<22} frames sent {after.frames_sent - before.frames_sent}, dropped "
            f"{after.frames_dropped - before.frames_dropped}; {after.realtime}"]


def measure_split(folder: Path, env: dict[str, str], setup: Setup, tally: dict[str, int]
                  ) -> list[str]:
    runtime = Runtime(folder / "split", env, setup.realtime)
    terminals = Terminals()
    names = ["busy", *(f"idle{n}" for n in range(1, setup.screens))]
    try:
        attach = [sys.executable, "-m", "hmi.cli", "attach", str(PROJECT), "--socket",
                  str(runtime.sock)]
        pids = [terminals.open(name, attach, env) for name in names]
        for name in names:
            _wait(lambda name=name: _started(terminals, name), f"the {name} screen")
        ended = _drive(terminals, "busy", setup.warm_s, [], setup.dialog_every)  # (warm-up)
        before = runtime.viewer.query()
        samplers = [Sampled(runtime.process.pid), *(Sampled(pid) for pid in pids)]
        t0 = time.monotonic()
        ended = ended or _drive(terminals, "busy", setup.seconds, samplers,
                                setup.dialog_every)
        elapsed = max(time.monotonic() - t0, 1e-3)
        after = runtime.viewer.query()
        runtime.viewer.leave()
    finally:
        terminals.close()
        runtime.stop()
    idle = [samplers[n + 1].line(f"idle screen {n}" if len(names) > 2 else "idle screen",
                                 elapsed) for n in range(1, len(names))]
    return [f"  split: one runtime, {len(names)} screens attached + the bench's viewer; "
            f"attach to first frame {runtime.first_frame_s * 1000:.0f} ms",
            *runtime.figures(before, after, elapsed, tally, "split runtime"),
            samplers[0].line("runtime memory", elapsed),
            samplers[1].line("screen with dialogs", elapsed), *idle,
            *([f"  {ended}"] if ended else [])]


HEL_CLAIM = 2 ** 31 - 1  # bytes the hostile HEL's header says its message has
STREAM_MOST = 64 << 20  # bytes the hostile client streams into one connection at most


def hostile_hel(port: int, seconds: float) -> tuple[int, int]:
    """An OPC UA client that sends a HEL claiming ~2 GiB, then streams data into it (at most
    STREAM_MOST a connection), over and over for `seconds`: as soon as a connection is
    closed, it opens the next. The bytes it sent and the connections it opened."""
    import contextlib
    import socket

    header = b"HELF" + HEL_CLAIM.to_bytes(4, "little")
    body = (0).to_bytes(4, "little") + (65536).to_bytes(4, "little") * 2 \
        + (0).to_bytes(4, "little") * 2
    sent = connections = 0
    end = time.monotonic() + seconds
    chunk = b"\0" * (1 << 16)
    while time.monotonic() < end:
        with contextlib.suppress(OSError), \
                socket.create_connection(("127.0.0.1", port), timeout=5.0) as s:
            connections += 1
            s.sendall(header + body)
            streamed = 0
            while streamed < STREAM_MOST and time.monotonic() < end:
                s.sendall(chunk)
                streamed += len(chunk)
                sent += len(chunk)
    return sent, connections


def measure_attack(folder: Path, env: dict[str, str], setup: Setup, tally: dict[str, int]
                   ) -> list[str]:
    """The runtime with its OPC UA gateway, one hostile client streaming into a HEL that
    claims 2 GiB for the whole window."""
    from hmi.bench.opcua import _free_port

    runtime = Runtime(folder / "attack", env, setup.realtime)
    port = _free_port()
    log = open(folder / "gateway.log", "wb")  # noqa: SIM115 (closed below)
    gateway = subprocess.Popen(
        [sys.executable, "-m", "hmi.cli", "gateway", str(PROJECT), "--socket",
         str(runtime.sock), "--opcua", f"opc.tcp://127.0.0.1:{port}"],
        stdin=subprocess.DEVNULL, stdout=log, stderr=log, env={**os.environ, **env})
    try:
        _wait(lambda: "serving" in (folder / "gateway.log").read_text(), "the gateway")
        time.sleep(setup.warm_s)
        samplers = [Sampled(runtime.process.pid), Sampled(gateway.pid)]
        sent: list[tuple[int, int]] = []
        attack = threading.Thread(
            target=lambda: sent.append(hostile_hel(port, setup.seconds)))
        before = runtime.viewer.query()
        t0 = time.monotonic()
        attack.start()
        while attack.is_alive():
            for sampler in samplers:
                sampler.sample()
            attack.join(1.0)
        elapsed = max(time.monotonic() - t0, 1e-3)
        for sampler in samplers:
            sampler.sample()
        after = runtime.viewer.query()
        runtime.viewer.leave()
    finally:
        runtime.stop()
        try:
            gateway.wait(START_S)
        except subprocess.TimeoutExpired:
            gateway.kill()
            gateway.wait()
        log.close()
    sent_bytes, connections = sent[0] if sent else (0, 0)
    return [f"  OPC UA HEL attack: the runtime, its gateway (plchmi gateway) and a client "
            f"whose HEL claims 2 GiB, then streams, reconnecting whenever closed "
            f"({sent_bytes / (1 << 20):.0f} MiB sent over {connections} connections in "
            f"{elapsed:.1f} s)",
            *runtime.figures(before, after, elapsed, tally, "runtime under the HEL attack"),
            samplers[0].line("runtime memory", elapsed),
            samplers[1].line("gateway memory", elapsed)]


# -- one process per HMI (before the split) -------------------------------------------------

def single_screen(stats: str) -> None:
    """One HMI with its cell's scans in its own process (SessionLink: the session read
    directly, as before the split), writing its figures to `stats` every half second."""
    from hmi.bench.ui import valve_session
    from hmi.link.local import SessionLink
    from hmi.ui.app import PlcHmiApp

    session = valve_session(PERIOD_US)
    link = SessionLink(session, live=True)
    app = PlcHmiApp(link, live=True)

    def write() -> None:
        while True:
            time.sleep(0.5)
            runner = link.runner
            if runner is None:
                continue
            figures = {"scans": session.engine.scan, "overruns": runner.overruns,
                       "p50": runner.lateness.percentile(0.5),
                       "p99": runner.lateness.percentile(0.99), "max": runner.lateness.most}
            Path(stats + ".new").write_text(json.dumps(figures))
            os.replace(stats + ".new", stats)

    threading.Thread(target=write, daemon=True).start()
    app.run()


def measure_single(folder: Path, env: dict[str, str], setup: Setup, tally: dict[str, int]
                   ) -> list[str]:
    terminals = Terminals()
    stats = {name: folder / f"{name}.json" for name in ("busy", "idle")}
    try:
        pids = {}
        for name in ("busy", "idle"):
            code = f"from hmi.bench.live import single_screen; single_screen({str(stats[name])!r})"
            pids[name] = terminals.open(name, [sys.executable, "-c", code], env)
        for name in ("busy", "idle"):
            _wait(lambda name=name: _started(terminals, name) and stats[name].exists(),
                  f"the {name} HMI")
        ended = _drive(terminals, "busy", setup.warm_s, [], setup.dialog_every)  # (warm-up)
        before = {name: json.loads(path.read_text()) for name, path in stats.items()}
        samplers = [Sampled(pids["busy"]), Sampled(pids["idle"])]
        t0 = time.monotonic()
        ended = ended or _drive(terminals, "busy", setup.seconds, samplers,
                                setup.dialog_every)
        elapsed = max(time.monotonic() - t0, 1e-3)
        time.sleep(0.6)  # (their figures as of the end)
        after = {name: json.loads(path.read_text()) for name, path in stats.items()}
    finally:
        terminals.close()
    lines = ["  one process per HMI: each HMI scans its own cell"]
    for name, label in (("busy", "HMI with dialogs"), ("idle", "idle HMI")):
        scans = after[name]["scans"] - before[name]["scans"]
        tally[f"one process, {label}"] = after[name]["overruns"] - before[name]["overruns"]
        lines.append(
            f"  {label:<22} {scans} scans in {elapsed:.1f} s "
            f"({scans * PERIOD_US / 1e6 / elapsed:.1%} of real time), "
            f"{after[name]['overruns'] - before[name]['overruns']} overruns; lateness since "
            f"start p50 {after[name]['p50']:.0f} us, p99 {after[name]['p99']:.0f} us, "
            f"max {after[name]['max'] / 1000:.1f} ms")
    lines.append(samplers[0].line("HMI with dialogs memory", elapsed))
    lines.append(samplers[1].line("idle HMI memory", elapsed))
    return lines + ([f"  {ended}"] if ended else [])


def _has_opcua() -> bool:
    import importlib.util
    return importlib.util.find_spec("asyncua") is not None


def run(args) -> None:
    import shutil

    if shutil.which("tmux") is None:
        print("  tmux is not installed: this section runs the HMIs in real terminals")
        return
    quick = getattr(args, "quick", False)
    minutes = getattr(args, "minutes", None)
    warm = getattr(args, "warm_minutes", None)
    setup = Setup(seconds=minutes * 60 if minutes else QUICK_SECONDS if quick else SECONDS,
                  warm_s=warm * 60 if warm else QUICK_WARM_S if quick else WARM_S,
                  screens=max(1, getattr(args, "screens", 2)),
                  dialog_every=max(0.05, getattr(args, "dialog_every", DIALOG_EVERY_S)),
                  realtime=not getattr(args, "no_realtime", False))
    print(f"  {PROJECT.name}, scan period {PERIOD_US // 1000} ms, {setup.seconds:g} s measured "
          f"per set-up after {setup.warm_s:g} s of warm-up; terminals {SIZE[0]}x{SIZE[1]}; a "
          f"dialog opened and closed every {setup.dialog_every:g} s; {load_line()}",
          flush=True)
    tally: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix="plchmi-bench-live-") as tmp:
        folder = Path(tmp)
        env = {"PLCHMI_DATA": str(folder / "data")}
        for line in measure_split(folder, env, setup, tally):
            print(line, flush=True)
        if not getattr(args, "split_only", False):
            for line in measure_single(folder, env, setup, tally):
                print(line, flush=True)
            if _has_opcua():
                for line in measure_attack(folder, env, setup, tally):
                    print(line, flush=True)
            else:
                print("  OPC UA HEL attack: not measured (asyncua is not installed)")
    print("  overruns in the measured window: " + "; ".join(
        f"{label} {count}" for label, count in tally.items()), flush=True)
    print(f"  after: {load_line()}", flush=True)
