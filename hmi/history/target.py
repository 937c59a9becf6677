"""Where a cell's history is kept (``--historian TARGET``), and a connection to it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hmi.history.store import Store, describe_url


@dataclass(frozen=True)
class Target:
    """Where a history is kept: a SQLite file, or a PostgreSQL server (its URL)."""

    kind: str  # sqlite, postgresql
    where: str  # the file's path, or the URL

    @property
    def path(self) -> Path:
        return Path(self.where)

    def describe(self) -> str:
        """For messages: the file, or the server without its password."""
        return self.where if self.kind == "sqlite" else describe_url(self.where)


POSTGRES_SCHEMES = ("postgresql://", "postgres://")


def parse_target(text: str) -> Target:
    """`--historian TARGET`: a postgresql:// URL, or a SQLite file's path."""
    if text.startswith(POSTGRES_SCHEMES):
        return Target("postgresql", text)
    if "://" in text:
        raise ValueError(f"{text!r}: not a history target (expected a SQLite file's path, "
                         "a postgresql:// URL, or off)")
    return Target("sqlite", text)


def open_store(target: Target, read_only: bool = False) -> Store:
    """A connection to `target`: the writer's, or a reader's (read-only)."""
    if target.kind == "sqlite":
        from hmi.history.sqlite import SqliteStore
        return SqliteStore(target.path, read_only)
    from hmi.history.postgres import PostgresStore
    return PostgresStore(target.where, read_only)


def default_target(cell: str) -> Target:
    """The cell's own SQLite file in the data folder, beside its journal."""
    from hmi.explain.journal import safe_file_name
    from hmi.paths import data_folder
    return Target("sqlite", str(data_folder() / safe_file_name(cell) / "history.sqlite"))
