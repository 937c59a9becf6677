"""The embedded history store: one SQLite file (standard library), in WAL mode.

WAL lets the trend screens read while the writer writes (a reader never waits for a batch,
nor the writer for a reader); each batch is one transaction, synced at its commit
(``synchronous=FULL``): a killed process, or a power cut, loses only the batch being written.
Samples sit in a table without rowid keyed by (signal, time), so a signal's window is one
range of the key, and a small whole number (a Boolean, a state) takes a byte or two.

The file is the cell's by default (``<data folder>/<project>/history.sqlite``), but it may
hold several cells, as a PostgreSQL database does: the schema and the statements are the
same (hmi.history.sql).
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hmi.history.sql import SqlStore
from hmi.history.store import SCHEMA_VERSION, StoreError

SCHEMA = """
CREATE TABLE IF NOT EXISTS plchmi_meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS plchmi_cells (id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE);
CREATE TABLE IF NOT EXISTS plchmi_signals (
    id INTEGER PRIMARY KEY, cell INTEGER NOT NULL, name TEXT NOT NULL, kind TEXT NOT NULL,
    description TEXT NOT NULL, grp TEXT NOT NULL, device TEXT NOT NULL, unit TEXT NOT NULL,
    labels TEXT NOT NULL, position INTEGER NOT NULL, UNIQUE (cell, name));
CREATE TABLE IF NOT EXISTS plchmi_samples (
    signal INTEGER NOT NULL, t INTEGER NOT NULL, value REAL NOT NULL,
    PRIMARY KEY (signal, t)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS plchmi_events (
    id INTEGER PRIMARY KEY, cell INTEGER NOT NULL, t INTEGER NOT NULL, type TEXT NOT NULL,
    event TEXT NOT NULL, key TEXT NOT NULL, severity TEXT NOT NULL, text TEXT NOT NULL,
    by TEXT NOT NULL, data TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS plchmi_events_t ON plchmi_events (cell, t);
CREATE TABLE IF NOT EXISTS plchmi_segments (
    id INTEGER PRIMARY KEY, cell INTEGER NOT NULL, start INTEGER NOT NULL,
    "end" INTEGER NOT NULL, source TEXT NOT NULL, clock TEXT NOT NULL);
"""


# The writer's page cache (KiB). SQLite's default, 2,000 KiB a connection, filled at about
# 0.8 MB an hour in the runtime (sqlite3_memory_used), the whole of its memory's growth; the
# writer appends to the tables' right edges, which a quarter of that holds.
WRITER_CACHE_KIB = 512


class SqliteStore(SqlStore):
    errors = (sqlite3.Error,)

    def __init__(self, path: Path, read_only: bool = False):
        super().__init__()
        self.where = str(path)
        self.read_only = read_only
        try:
            if read_only:
                if not path.is_file():
                    raise StoreError(f"{path}: no history here yet")
                self.db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True,
                                          check_same_thread=False, isolation_level=None)
            else:
                path.parent.mkdir(parents=True, exist_ok=True)
                self.db = sqlite3.connect(str(path), check_same_thread=False,
                                          isolation_level=None)
            self.db.execute("PRAGMA busy_timeout = 10000")
            if not read_only:
                self.db.execute("PRAGMA journal_mode = WAL")
                self.db.execute("PRAGMA synchronous = FULL")
                self.db.execute(f"PRAGMA cache_size = -{WRITER_CACHE_KIB}")
                self.db.executescript(SCHEMA)
                self.db.execute("INSERT OR IGNORE INTO plchmi_meta VALUES ('schema', ?)",
                                (str(SCHEMA_VERSION),))
            try:
                self.check_schema(self.db)
            except sqlite3.OperationalError:  # no such table: some other SQLite file
                raise StoreError(f"{path}: not a plchmi history") from None
        except sqlite3.Error as exc:
            raise StoreError(f"{path}: {self.words(exc)}") from None
        except OSError as exc:
            raise StoreError(f"{path}: {exc.strerror or exc}") from None

    @contextlib.contextmanager
    def transaction(self, db: Any) -> Iterator[None]:
        db.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            with contextlib.suppress(sqlite3.Error):
                db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")

    # (a bare column beside max(): SQLite takes it from the row with the greatest t)
    bucket_sql = ("SELECT ((t - ?) * ? + ? - 1) / ? - 1 AS c, count(*), min(value), "
                  "max(value), value, max(t) FROM plchmi_samples WHERE signal = ? AND t > ? "
                  "AND t <= ? GROUP BY c ORDER BY c")

    def words(self, exc: Exception) -> str:
        """SQLite's message, with what it means for the history when it is a known one."""
        text = str(exc)
        if "disk is full" in text:
            return "the disk is full (history cannot be written)"
        if "readonly" in text or "read-only" in text:
            return f"{text} (no permission to write the history)"
        if "not a database" in text:
            return "not a history database (not a SQLite file)"
        return text
