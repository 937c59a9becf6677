"""Where plchmi finds the example projects and the component library (the repository's
folders), and where it writes its data (journals, crash reports, soak step lists)."""

import os
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PROJECTS = REPO / "projects"
COMPONENTS = REPO / "components"  # the component library (docs/project-format.md)


def data_folder() -> Path:
    """$PLCHMI_DATA, else $XDG_DATA_HOME/plchmi, else ~/.local/share/plchmi."""
    if os.environ.get("PLCHMI_DATA"):
        return Path(os.environ["PLCHMI_DATA"])
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "plchmi"
