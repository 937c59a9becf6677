"""A project as its files, for a worker that may not share this machine's disks.

A worker of a cluster runs on another machine, with its own installation of plchmi: the
project travels as the bytes of the files it was loaded from (those inside its folder; the
component library's are the worker's own, pinned by the code version), and is loaded there
from a private temporary folder. The digest names the project as loaded — its files inside
and outside its folder, and the diagnoser variant — so a worker checks that what it loaded is
what was sent.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import threading
from dataclasses import dataclass
from multiprocessing.util import Finalize
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.paths import COMPONENTS

if TYPE_CHECKING:
    from hmi.project.model import Project


class BundleError(Exception):
    """A project that cannot travel, or that a worker loaded differently."""


@dataclass(frozen=True)
class Bundle:
    name: str  # the project folder's name (the worker's copy has the same)
    project_file: str  # the project file, relative to the folder
    variant: str | None  # the diagnoser variant loaded (--diagnoser)
    files: tuple[tuple[str, bytes], ...]  # (path relative to the folder, content)
    # The component library's files it uses: (the path from the project folder to the file,
    # as its `use:` reaches it, e.g. ../../components/valve.yaml; the file in the library)
    library: tuple[tuple[str, str], ...]
    digest: str  # sha256 of the project as loaded (see digest_of)
    # A diagnosers file loaded in place of the project's (`--diagnoser FILE.yaml`): its
    # content, written beside the worker's copy and loaded from there.
    diagnosers: bytes | None = None

    @classmethod
    def of(cls, project: Project, variant: str | None = None) -> Bundle:
        folder = project.path.resolve()
        library_root = COMPONENTS.resolve()
        inside: list[tuple[str, bytes]] = []
        library: list[tuple[str, str]] = []
        override = _diagnosers_file(variant)
        diagnosers = None
        for name in project.files:
            path = Path(name).resolve()
            if override is not None and path == override:
                diagnosers = path.read_bytes()
            elif path.is_relative_to(folder):
                inside.append((path.relative_to(folder).as_posix(), path.read_bytes()))
            elif path.is_relative_to(library_root):
                library.append((Path(os.path.relpath(path, folder)).as_posix(),
                                path.relative_to(library_root).as_posix()))
            else:
                raise BundleError(f"project {project.name}: {name} is neither in its folder "
                                  "nor in the component library")
        if not inside:
            raise BundleError(f"project {project.name}: no file of it lies in {folder}")
        return cls(folder.name, inside[0][0], None if override else variant, tuple(inside),
                   tuple(library), digest_of(project, variant), diagnosers)

    def load(self) -> Project:
        """The project, loaded from a private copy of its files (kept until the process
        ends: the soak reads its project folder again at each session); checked to be the
        project that was sent."""
        from hmi.project.loader import load_project
        with _LOCK:  # a Dask worker may run several shards at once, in threads
            folder = self.folder
            if not folder.exists():
                staging = folder.with_name(folder.name + ".part")
                for relative, content in self.files:
                    target = staging / relative
                    target.parent.mkdir(parents=True, exist_ok=True)
                    target.write_bytes(content)
                # The library's files where the project's `use:` paths lead from the copy:
                # links to this worker's own library (the loader follows a link and finds
                # the file inside the library, as it would from the original folder).
                for relative, in_library in self.library:
                    target = Path(os.path.normpath(folder / relative))
                    if not target.exists():
                        target.parent.mkdir(parents=True, exist_ok=True)
                        target.symlink_to(COMPONENTS.resolve() / in_library)
                staging.rename(folder)
            variant = self.variant
            if self.diagnosers is not None:
                variant = str(folder.with_name(folder.name + ".diagnosers.yaml"))
                if not Path(variant).exists():
                    Path(variant).write_bytes(self.diagnosers)
        project = load_project(folder / self.project_file, variant)
        found = digest_of(project, variant)
        if found != self.digest:
            raise BundleError(f"project {self.name} loads differently on this worker (digest "
                              f"{found[:12]}, sent {self.digest[:12]}): its component library "
                              "differs from the one the study was started with")
        return project

    @property
    def folder(self) -> Path:
        """Where :meth:`load` puts the files on this worker: as many folders deep in its
        scratch tree as the library's files are folders above the project (`..` from the
        copy stays inside the tree)."""
        ups = max((Path(relative).parts.count("..") for relative, _ in self.library),
                  default=0)
        return _scratch().joinpath(self.digest[:16], *["up"] * max(0, ups - 1), self.name)


def digest_of(project: Project, variant: str | None) -> str:
    """sha256 of the project's files, each named relative to its folder or to the component
    library (the same project gives the same digest wherever it is loaded from)."""
    folder = project.path.resolve()
    override = _diagnosers_file(variant)
    h = hashlib.sha256(f"variant={'' if override else variant or ''}\0".encode())
    for name in project.files:
        path = Path(name).resolve()
        if override is not None and path == override:
            where = "diagnosers-file"
        elif path.is_relative_to(folder):
            where = "project/" + path.relative_to(folder).as_posix()
        elif path.is_relative_to(COMPONENTS.resolve()):
            where = "library/" + path.relative_to(COMPONENTS.resolve()).as_posix()
        else:
            where = "other/" + path.name
        h.update(where.encode() + b"\0")
        try:
            h.update(path.read_bytes())
        except OSError:
            h.update(b"?")
        h.update(b"\0")
    return h.hexdigest()


def _diagnosers_file(variant: str | None) -> Path | None:
    from hmi.project.loader import is_diagnosers_file
    return Path(str(variant)).resolve() if is_diagnosers_file(variant) else None


_SCRATCH: dict[int, Path] = {}  # per process id: a forked worker makes its own
_LOCK = threading.Lock()


def _scratch() -> Path:
    """This process's temporary folder for the projects it was sent, removed when it ends
    (atexit for a main process, multiprocessing's finalizers for a pool's worker, which
    leaves without running atexit)."""
    pid = os.getpid()
    if pid not in _SCRATCH:
        path = Path(tempfile.mkdtemp(prefix="plchmi-farm-"))
        _SCRATCH[pid] = path
        atexit.register(shutil.rmtree, path, True)
        Finalize(None, shutil.rmtree, args=(path, True), exitpriority=0)
    return _SCRATCH[pid]
