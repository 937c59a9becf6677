"""Regenerate ``screenshots/*.svg`` from the real app in its main states.

    python -m hmi.ui.screenshots [--out screenshots] [--only NAME ...]

The states are those of :mod:`hmi.ui.scenarios` (the snapshot tests use the same), reached by
pressing the operator's keys in virtual time, so the pictures are exactly repeatable.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from textual.pilot import Pilot

from hmi.ui.scenarios import SCENARIOS, Scenario

DEFAULT_OUT = Path(__file__).resolve().parents[2] / "screenshots"


def shoot(scenario: Scenario, out: Path) -> Path:
    app = scenario.make()
    path = out / f"{scenario.name}.svg"

    async def auto_pilot(pilot: Pilot) -> None:
        await scenario.run(pilot)
        await pilot.pause()
        await pilot.wait_for_scheduled_animations()
        app.save_screenshot(filename=path.name, path=str(out))
        app.exit()

    app.title = f"plchmi — {scenario.description}"
    app.run(headless=True, size=scenario.size, auto_pilot=auto_pilot)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hmi.ui.screenshots",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    parser.add_argument("--only", nargs="*", metavar="NAME",
                        help="scenarios to shoot: " + ", ".join(s.name for s in SCENARIOS))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    chosen = [s for s in SCENARIOS if not args.only or s.name in args.only]
    for scenario in chosen:
        path = shoot(scenario, args.out)
        print(f"{path}  {scenario.size[0]}×{scenario.size[1]}  {scenario.description}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
