"""The operator HMI (Textual). Reads engine snapshots; sends commands through the controller."""

from __future__ import annotations

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.widgets import DataTable, Footer, Static

from hmi.engine.commands import FaultReset, Pause, Resume, StepScans
from hmi.engine.live import LiveRunner
from hmi.engine.runner import Controller
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.timefmt import seconds

REFRESH_HZ = 20


class PlcHmiApp(App):
    CSS_PATH = "app.tcss"
    TITLE = "plchmi"
    BINDINGS = [
        Binding("space", "toggle_run", "Run/Pause"),
        Binding("s", "step", "Step"),
        Binding("r", "fault_reset", "Fault reset"),
        Binding("q", "quit", "Quit"),
    ]

    def __init__(self, controller: Controller, live: bool = True):
        super().__init__()
        self.controller = controller
        self.live = live
        self.runner: LiveRunner | None = None
        self._shown_scan = -1

    def compose(self) -> ComposeResult:
        yield Static(id="status")
        yield DataTable(id="io", cursor_type="row")
        yield Static(id="steps")
        yield Static(id="message")
        yield Footer()

    def on_mount(self) -> None:
        table = self.query_one("#io", DataTable)
        for label in ("Variable", "Kind", "Value", "Functional", "Description"):
            table.add_column(label, key=label)
        project = self.controller.engine.project
        for var in project.inputs:
            table.add_row(var.name, "input", "", "", var.description, key=var.name)
        for var in project.outputs:
            table.add_row(var.name, "output", "", "", var.description, key=var.name)
        if self.controller.engine.last is None:
            self.controller.scan_once()
        self.refresh_view()
        self.set_interval(1 / REFRESH_HZ, self.refresh_view)
        if self.live:
            self.runner = LiveRunner(self.controller)
            self.runner.start()

    def on_unmount(self) -> None:
        if self.runner:
            self.runner.stop()

    def refresh_view(self) -> None:
        snap = self.controller.engine.last
        if snap is None or snap.scan == self._shown_scan:
            self._status(snap)
            return
        self._shown_scan = snap.scan
        self._status(snap)
        table = self.query_one("#io", DataTable)
        for name in snap.layout.inputs:
            table.update_cell(name, "Value", _bit(snap.value(name)))
        for name, fov, out in zip(snap.layout.outputs, snap.fov, snap.outputs, strict=True):
            table.update_cell(name, "Value", _bit(out))
            table.update_cell(name, "Functional", _bit(fov))
        self.query_one("#steps", Static).update(
            "Active steps: " + (" ".join(snap.active_steps) or "-"))

    def _status(self, snap: Snapshot | None) -> None:
        engine = self.controller.engine
        run = self.controller.state.label.upper()
        scan = f"scan {snap.scan}  t={seconds(snap.time_us)} s" if snap else "no scan yet"
        plant = engine.plant.status
        link = "" if plant.connected else f"  |  PLANT DISCONNECTED: {plant.message}"
        latched = f"  |  OUTPUTS SAFE: {snap.latched[-1].detail}" if snap and snap.latched \
            else ""
        overruns = f"  |  overruns {self.runner.overruns}" if self.runner and \
            self.runner.overruns else ""
        self.query_one("#status", Static).update(
            f"{engine.project.name}  |  {plant.description}  |  "
            f"{engine.mode.upper()}  |  policy {engine.policy}  |  {run}  |  {scan}"
            f"{link}{latched}{overruns}")

    def action_toggle_run(self) -> None:
        running = self.controller.state.running
        result = self.controller.command(Pause() if running else Resume())
        self.query_one("#message", Static).update(result.message)

    def action_fault_reset(self) -> None:
        result = self.controller.command(FaultReset())
        self.query_one("#message", Static).update(result.message)

    def action_step(self) -> None:
        result = self.controller.command(StepScans(1))
        self.query_one("#message", Static).update(result.message)
        self.refresh_view()


def _bit(value: bool) -> str:
    return "1" if value else "0"


def run_app(engine: Engine, clock=None) -> int:
    """Run the HMI; a real plant passes a wall clock to stamp its scans (see WallClock)."""
    app = PlcHmiApp(Controller(engine, clock=clock))
    app.run()
    return 0
