"""Where the example projects live (the repository's projects/ folder)."""

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PROJECTS = REPO / "projects"
COMPONENTS = REPO / "components"  # the component library (docs/project-format.md)
