"""The loaded project, kept across processes for the HMI's start (docs/performance.md).

Loading a project (its YAML composed, every name declared, every expression parsed and
checked) took about 23 ms of CPU of the HMI's start for cispi_valve, and importing PyYAML
another 14 ms; reading back the :class:`~hmi.project.model.Project` it gave takes about 1 ms
(it is plain immutable data, pickled). The kept project may only stand in for a load that
would give the same project, so its key is a digest of everything the load depends on:

* the files it can read: the loader reads only inside the project's folder and the component
  library (hmi.project.confine refuses anything else, symlinks followed), so both trees are
  walked: every entry's name and kind, every symlink's target and every file's content.
  A file edited, added, removed or relinked is a different key;
* the loader's code: every file of the hmi package by name, size and modification time (the
  rule Python's own bytecode cache follows for the modules' code);
* what it was asked: the path as given, the working directory (messages and positions show
  paths relative to it), the diagnoser variant, the interpreter.

Only a successful load is kept: a project with errors is loaded, and its errors reported, as
without the cache. A folder too big to walk in a millisecond or two (more than MAX_ENTRIES
entries or MAX_BYTES of files) is loaded every time. The files sit beside hmi's bytecode,
one per key, written under the bytecode's rule (hmi/codecache.py) and trusted as it is.
"""

from __future__ import annotations

import os
import pickle
import sys
from collections.abc import Iterator
from pathlib import Path

from hmi.codecache import blake2b, read_file, write_file, writing
from hmi.paths import COMPONENTS
from hmi.project.loader import is_diagnosers_file, load_project, resolve_project_file
from hmi.project.model import Project

PACKAGE = Path(__file__).resolve().parents[1]  # hmi/
DEFAULT_DIR = PACKAGE / "__pycache__"
PREFIX = "project-"
SUFFIX = f".{sys.implementation.cache_tag}.pickle"
HEADER = b"plchmi kept project 1\n"
MAX_ENTRIES = 400  # per tree walked; a project folder holds a handful of files
MAX_BYTES = 4 << 20
MAX_KEPT = 8  # projects kept; past this the oldest goes


class TooBig(Exception):
    """A tree to walk beyond MAX_ENTRIES or MAX_BYTES: not worth keeping."""


def load(path: str | Path, diagnoser_variant: str | None = None,
         folder: Path = DEFAULT_DIR, write: bool | None = None) -> Project:
    """``load_project(path, diagnoser_variant)``, read back from what an earlier process kept
    if everything the load depends on is unchanged (module docstring), else loaded and kept."""
    try:
        if is_diagnosers_file(diagnoser_variant):  # a file the key does not cover
            raise ValueError(diagnoser_variant)
        key = project_key(path, diagnoser_variant)
    except (OSError, ValueError, TooBig):  # loaded as usual (it reports what is wrong)
        return load_project(path, diagnoser_variant)
    file = folder / f"{PREFIX}{key}{SUFFIX}"
    kept = _read(file)
    if kept is not None:
        return kept
    project = load_project(path, diagnoser_variant)
    if writing(write) and not is_diagnosers_file(diagnoser_variant):
        write_file(file, HEADER, pickle.dumps(project, pickle.HIGHEST_PROTOCOL))
        _forget_old(folder)
    return project


def load_once(path: str | Path, diagnoser_variant: str | None = None) -> Project:
    """``load_project(path, diagnoser_variant)``, loaded once in this process while nothing
    it reads changes (the key of :func:`project_key` without the code: a process runs one
    version of it). For the pilot tests and the screenshots, which start an app about a
    hundred times per process on the same few projects: each load took ~30 ms of an app
    start's ~0.26 s of CPU; the key, ~1 ms. The project is immutable data, shared."""
    try:
        if is_diagnosers_file(diagnoser_variant):  # a file the key does not cover
            raise ValueError(diagnoser_variant)
        key = project_key(path, diagnoser_variant, code=False)
    except (OSError, ValueError, TooBig):  # loaded as usual (it reports what is wrong)
        return load_project(path, diagnoser_variant)
    project = _LOADED.pop(key, None)
    if project is None:
        project = load_project(path, diagnoser_variant)
    _LOADED[key] = project  # the most recent last
    while len(_LOADED) > MAX_LOADED:
        del _LOADED[next(iter(_LOADED))]
    return project


_LOADED: dict[str, Project] = {}
MAX_LOADED = 16


def project_key(path: str | Path, diagnoser_variant: str | None, code: bool = True) -> str:
    """The digest of what loading `path` depends on (module docstring); `code`: hmi's
    files too (across processes)."""
    digest = blake2b(digest_size=20)

    def add(*parts: object) -> None:
        digest.update(repr(parts).encode("utf-8", "surrogatepass"))

    project_file = resolve_project_file(path)
    add("asked", str(path), diagnoser_variant, os.getcwd(), str(Path.cwd().resolve()),
        sys.implementation.cache_tag, sys.version)
    add("project file", str(project_file), str(project_file.resolve()))
    for root in (project_file.parent, COMPONENTS):
        add("tree", str(root), str(root.resolve()))
        _tree(root.resolve(), digest)
    if code:
        add("code")
        _code(PACKAGE, digest)
    return digest.hexdigest()


def _entries(root: Path, skip: str | None = None) -> Iterator[os.DirEntry[str]]:
    """Every entry under `root` in a fixed order, not following symlinks (folders named
    `skip` listed, not entered)."""
    pending = [root]
    while pending:
        with os.scandir(pending.pop()) as listing:
            found = sorted(listing, key=lambda e: e.name)
        for entry in found:
            if entry.is_dir(follow_symlinks=False) and entry.name != skip:
                pending.append(Path(entry.path))
            yield entry


def _tree(root: Path, digest: blake2b, *, relative: bool = False,
          others: str = "refuse") -> None:
    """Every entry under `root` (symlinks not followed: their targets are recorded, and
    what they lead to must lie in a tree walked too): name, kind, content. Names are the
    full paths, or with `relative` the paths under `root` (a fingerprint that must not
    depend on where the folder is). A fifo, a socket or a device: with `others="refuse"`
    the tree cannot be kept (the loader refuses them); with "skip" it is not read (a
    runtime's own socket in a data folder)."""
    size = 0
    for count, entry in enumerate(_entries(root), start=1):
        if count > MAX_ENTRIES:
            raise TooBig(str(root))
        name = os.path.relpath(entry.path, root) if relative else entry.path
        if entry.is_symlink():
            record = f"link {name} -> {os.readlink(entry.path)}"
        elif entry.is_dir():
            record = f"dir {name}"
        elif entry.is_file():
            with open(entry.path, "rb") as file:
                content = file.read(MAX_BYTES - size + 1)
            size += len(content)
            if size > MAX_BYTES:
                raise TooBig(str(root))
            record = f"file {name} {len(content)}"
            digest.update(content)
        elif others == "skip":
            continue
        else:
            raise TooBig(entry.path)
        digest.update(f"{record}\0".encode("utf-8", "surrogateescape"))


def _code(package: Path, digest: blake2b) -> None:
    """hmi's files by name, size and modification time (not its bytecode)."""
    for entry in _entries(package, skip="__pycache__"):
        if not entry.is_dir(follow_symlinks=False):
            stat = entry.stat()
            digest.update(f"{entry.path} {stat.st_size} {stat.st_mtime_ns}\0".encode(
                "utf-8", "surrogateescape"))


def _read(file: Path) -> Project | None:
    body = read_file(file, HEADER)
    if body is None:
        return None
    try:
        project = pickle.loads(body)
    except Exception:  # damaged, or of classes since changed: loaded again
        return None
    return project if isinstance(project, Project) else None


def _forget_old(folder: Path) -> None:
    """Keep the MAX_KEPT most recently written projects (tests and hand runs load many)."""
    try:
        kept = sorted((p for p in folder.iterdir()
                       if p.name.startswith(PREFIX) and p.name.endswith(SUFFIX)),
                      key=lambda p: p.stat().st_mtime_ns)
        for old in kept[:-MAX_KEPT]:
            old.unlink()
    except OSError:
        pass


def fingerprint(path: str | Path, diagnoser_variant: str | None) -> str:
    """Which project a process loaded, to compare with another process's: a digest of the
    files the load reads (the project's folder and the component library, by their names
    under those folders and their contents) and the diagnoser variant; not where the
    folders are nor how the path was written, so a runtime and a screen started from
    different folders agree on the same files. A folder beyond the limits of a kept project
    (MAX_ENTRIES, MAX_BYTES) raises TooBig."""
    digest = blake2b(digest_size=16)
    project_file = resolve_project_file(path).resolve()
    digest.update(repr(("variant", diagnoser_variant, project_file.name)).encode())
    for label, root in (("project", project_file.parent), ("components", COMPONENTS.resolve())):
        digest.update(f"tree {label}\0".encode())
        _tree(root, digest, relative=True, others="skip")
    return digest.hexdigest()
