"""An SVG picture of the screen, from the palette, saved where the operator can find it.

Textual's own palette entry saves to ~/Downloads and, when that folder is missing, fails
without a word; its SVGs run coloured words together in viewers that drop the spaces opening
a text run (`spcRun/Pause`, `SIMULATIONposition`). This one writes to the folder the HMI was
started in, says where (or why not), and marks the SVG's spaces as text
(``xml:space="preserve"``, as tests/screenshots.py does for the documentation's pictures).
"""

from __future__ import annotations

import time
from pathlib import Path

PRESERVE = '<svg xml:space="preserve" '


def preserve_spaces(svg: str) -> str:
    """Say on the SVG's root that its spaces are text; idempotent."""
    return svg if PRESERVE in svg else svg.replace("<svg ", PRESERVE, 1)


def screenshot_name(project: str, now: float | None = None) -> str:
    """'plchmi_cispi_valve_2026-11-29T10-15-00.svg' (no character a file system refuses)."""
    stamp = time.strftime("%Y-%m-%dT%H-%M-%S", time.localtime(now))
    return f"plchmi_{project}_{stamp}.svg"


def save_svg(svg: str, folder: Path, name: str) -> Path:
    """Write the picture; an OSError (a read-only or missing folder) is the caller's to say."""
    path = folder / name
    path.write_text(preserve_spaces(svg), encoding="utf-8")
    return path
