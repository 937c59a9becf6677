"""Where a project may read files from: its own folder, and the component library.

A project names other files (`include:`, a component's `use:`); a project received from
someone else must not make plchmi read /etc/passwd and quote its first line in an error, nor
reach outside through `../..` or a symlink. Each name is resolved (symlinks followed) and
must land inside one of the allowed folders; otherwise it is refused without opening the
file. docs/project-format.md states the rule.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath

from hmi.paths import COMPONENTS

MAX_PATH_CHARS = 1024  # far beyond any real include, below every system's PATH_MAX
MAX_PART_CHARS = 255  # NAME_MAX of common file systems


@dataclass
class Refused(Exception):
    """A file name a project may not use; `message` is said at the name's position."""

    message: str
    expected: str


def confined_file(folder: Path, name: str, roots: Sequence[tuple[Path, str]], what: str) -> Path:
    """The file `name` names relative to `folder`, resolved, if it lies in one of `roots`
    ((folder, how the message calls it)); else Refused. The file is not opened here."""
    places = " or ".join(label for _, label in roots)
    if not name.strip():
        raise Refused(f"{what} is empty", f"a file name relative to {places}")
    if len(name) > MAX_PATH_CHARS or any(len(p) > MAX_PART_CHARS for p in PurePath(name).parts):
        raise Refused(f"{what} is too long a file name",
                      f"a path of at most {MAX_PATH_CHARS} characters, {MAX_PART_CHARS} per "
                      "folder or file name")
    if PurePath(name).is_absolute() or name.startswith("~"):
        raise Refused(f"{what} {name!r} is an absolute path",
                      f"a file name relative to the project folder, inside {places}")
    try:
        path = (folder / name).resolve()
        allowed = [(root.resolve(), label) for root, label in roots]
    except (OSError, RuntimeError) as exc:  # a symlink loop, a name the system refuses
        raise Refused(f"{what} {name!r} cannot be resolved ({exc.__class__.__name__})",
                      f"a file inside {places}") from None
    if not any(path.is_relative_to(root) for root, _ in allowed):
        raise Refused(f"{what} {name!r} leads outside {places}; it is not read",
                      f"a file inside {places} (symlinks and '..' are followed before "
                      "checking)")
    return path


def project_roots(folder: Path) -> list[tuple[Path, str]]:
    return [(folder, "the project folder")]


def component_roots(folder: Path) -> list[tuple[Path, str]]:
    return [(folder, "the project folder"), (COMPONENTS, "the component library")]
