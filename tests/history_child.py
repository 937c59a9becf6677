"""A runtime for tests/test_history_kill.py to kill: the valve in real time (the HMI's scan
thread, a simulated plant) with its historian writing to TARGET, printing each scan's wall
time (microseconds since the epoch) as soon as the scan has been recorded.

    python tests/history_child.py TARGET EPOCH_US
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from hmi.engine.scan import Engine  # noqa: E402
from hmi.history.historian import Historian  # noqa: E402
from hmi.history.target import parse_target  # noqa: E402
from hmi.plant.sim.plant import SimPlant  # noqa: E402
from hmi.project.loader import load_project  # noqa: E402
from hmi.session.live import LiveRunner  # noqa: E402
from hmi.session.session import Session  # noqa: E402


def main() -> None:
    target, epoch = parse_target(sys.argv[1]), int(sys.argv[2])
    project = load_project(ROOT / "projects" / "cispi_valve")
    session = Session(Engine(project, SimPlant(project)))
    session.epoch_us = epoch
    Historian(session, target, source="test").attach()
    out = sys.stdout

    def told(cell) -> None:  # after the historian's listener: this scan is queued
        out.write(f"{epoch + cell.snapshot.time_us}\n")
        out.flush()
    session.scan_listeners.append(told)
    LiveRunner(session).start()
    threading.Event().wait()  # until killed


if __name__ == "__main__":
    main()
