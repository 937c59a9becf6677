"""Regenerate ``screenshots/*.svg`` from the real app in its main states.

    python tests/screenshots.py [--out screenshots] [--only NAME ...] [--png DIR]

The states are those of tests/ui_scenarios.py (the snapshot tests use the same), reached by
pressing the operator's keys in virtual time, so the pictures are exactly repeatable.

``--png DIR`` also converts each SVG to a PNG (1400 px wide, white background) with
``rsvg-convert`` (Debian's librsvg2-bin), to look at them without a browser. librsvg drops
the spaces that open a text run unless told to keep them, which shifts coloured words left
(`conveyorFAULTY`, `P110.830 s`). The SVGs are written with ``xml:space="preserve"`` on their
root, so that every viewer keeps those spaces (librsvg, and browsers, which otherwise treat a
run's opening spaces as XML white space); the app also closes each gap in the run before it
(hmi.ui.style.gap), so a viewer that still drops them loses no column.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from textual.pilot import Pilot
from ui_scenarios import SCENARIOS, Scenario

from hmi.ui.headless import drain
from hmi.ui.screenshot import preserve_spaces

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "screenshots"


def shoot(scenario: Scenario, out: Path) -> Path:
    app = scenario.make()
    path = out / f"{scenario.name}.svg"

    async def auto_pilot(pilot: Pilot) -> None:
        await scenario.run(pilot)
        await drain(pilot)
        await pilot.wait_for_scheduled_animations()
        app.save_screenshot(filename=path.name, path=str(out))
        preserve(path)
        app.exit()

    app.title = f"plchmi — {scenario.description}"
    app.run(headless=True, size=scenario.size, auto_pilot=auto_pilot)
    return path


def preserve(svg: Path) -> None:
    """Say on the SVG's root that its spaces are text (see above); idempotent."""
    svg.write_text(preserve_spaces(svg.read_text(encoding="utf-8")), encoding="utf-8")


def to_png(svg: Path, png: Path, width: int = 1400) -> None:
    """Convert with rsvg-convert, keeping the spaces that open a text run (see above)."""
    text = preserve_spaces(svg.read_text(encoding="utf-8"))
    with tempfile.NamedTemporaryFile("w", suffix=".svg", encoding="utf-8") as tmp:
        tmp.write(text)
        tmp.flush()
        subprocess.run(["rsvg-convert", "-w", str(width), "-b", "white", tmp.name,
                        "-o", str(png)], check=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python tests/screenshots.py",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    parser.add_argument("--only", nargs="*", metavar="NAME",
                        help="scenarios to shoot: " + ", ".join(s.name for s in SCENARIOS))
    parser.add_argument("--png", type=Path, metavar="DIR",
                        help="also write PNGs there (needs rsvg-convert)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.png is not None:
        if shutil.which("rsvg-convert") is None:
            parser.error("--png needs rsvg-convert (apt-get install librsvg2-bin)")
        args.png.mkdir(parents=True, exist_ok=True)
    chosen = [s for s in SCENARIOS if not args.only or s.name in args.only]
    for scenario in chosen:
        path = shoot(scenario, args.out)
        print(f"{path}  {scenario.size[0]}×{scenario.size[1]}  {scenario.description}")
        if args.png is not None:
            to_png(path, args.png / f"{scenario.name}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
