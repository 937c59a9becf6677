"""The history in PostgreSQL (psycopg 3): several cells, years, one database.

The schema is the SQLite store's (hmi.history.sqlite), with the samples and the events
partitioned by calendar month (UTC), as Ignition's tag historian does: a month's partition
is created when a batch first needs it, and retention, once it has deleted a cell's rows
before the cutoff, drops the partitions left empty (their space comes back at once, with no
vacuum). Partitions are shared by the cells of the database, so retention deletes per cell
(cells may keep their history for different times) and only drops what no cell still uses.

``--historian postgresql://USER@HOST/DB`` (any libpq URL: ``?host=/run/postgresql`` for a
socket, a password in ``~/.pgpass`` or the URL). Needs the extra: ``pip install
'plchmi[postgres]'``. A reader connects read-only (``default_transaction_read_only``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from datetime import UTC, datetime
from typing import Any

from hmi.history.sql import SqlStore
from hmi.history.store import SCHEMA_VERSION, StoreError, describe_url

NEEDS_EXTRA = ("a PostgreSQL history needs psycopg: pip install 'plchmi[postgres]' "
               "(or a SQLite file: --historian PATH)")
CONNECT_TIMEOUT_S = 5

SCHEMA = """
CREATE TABLE IF NOT EXISTS plchmi_meta (key text PRIMARY KEY, value text NOT NULL);
CREATE TABLE IF NOT EXISTS plchmi_cells (id serial PRIMARY KEY, name text NOT NULL UNIQUE);
CREATE TABLE IF NOT EXISTS plchmi_signals (
    id serial PRIMARY KEY, cell integer NOT NULL, name text NOT NULL, kind text NOT NULL,
    description text NOT NULL, grp text NOT NULL, device text NOT NULL, unit text NOT NULL,
    labels text NOT NULL, position integer NOT NULL, UNIQUE (cell, name));
CREATE TABLE IF NOT EXISTS plchmi_samples (
    signal integer NOT NULL, t bigint NOT NULL, value double precision NOT NULL,
    PRIMARY KEY (signal, t)) PARTITION BY RANGE (t);
CREATE TABLE IF NOT EXISTS plchmi_events (
    id bigserial, cell integer NOT NULL, t bigint NOT NULL, type text NOT NULL,
    event text NOT NULL, key text NOT NULL, severity text NOT NULL, text text NOT NULL,
    by text NOT NULL, data text NOT NULL, PRIMARY KEY (t, id)) PARTITION BY RANGE (t);
CREATE INDEX IF NOT EXISTS plchmi_events_cell_t ON plchmi_events (cell, t);
CREATE TABLE IF NOT EXISTS plchmi_segments (
    id serial PRIMARY KEY, cell integer NOT NULL, start bigint NOT NULL,
    "end" bigint NOT NULL, source text NOT NULL, clock text NOT NULL);
"""
PARTITIONED = ("plchmi_samples", "plchmi_events")


def month_of(t_us: int) -> tuple[int, int]:
    when = datetime.fromtimestamp(t_us // 1_000_000, UTC)
    return when.year, when.month


def month_bounds(year: int, month: int) -> tuple[int, int]:
    """The first microsecond of a month (UTC) and of the next."""
    start = datetime(year, month, 1, tzinfo=UTC)
    end = datetime(year + month // 12, month % 12 + 1, 1, tzinfo=UTC)
    return int(start.timestamp()) * 1_000_000, int(end.timestamp()) * 1_000_000


class PostgresStore(SqlStore):
    def __init__(self, url: str, read_only: bool = False):
        super().__init__()
        try:
            import psycopg
        except ImportError:
            raise StoreError(NEEDS_EXTRA) from None
        self.psycopg = psycopg
        self.errors = (psycopg.Error,)
        self.where = describe_url(url)
        self.read_only = read_only
        self._partitions: set[str] = set()
        try:
            self.db = psycopg.connect(url, autocommit=True, connect_timeout=CONNECT_TIMEOUT_S)
        except psycopg.Error as exc:
            raise StoreError(f"{self.where}: {self.words(exc)}") from None
        try:
            if read_only:
                self.db.execute("SET default_transaction_read_only = on")
            else:
                with self.db.transaction():
                    # one writer at a time creates the schema (two cells starting together)
                    self.db.execute("SELECT pg_advisory_xact_lock(727100)")
                    self.db.execute(SCHEMA)
                    self.db.execute("INSERT INTO plchmi_meta VALUES ('schema', %s) "
                                    "ON CONFLICT DO NOTHING", (str(SCHEMA_VERSION),))
            self.check_schema(self.db)
        except psycopg.errors.UndefinedTable:
            self.db.close()
            raise StoreError(f"{self.where}: no plchmi history in this database") from None
        except psycopg.Error as exc:
            self.db.close()
            raise StoreError(f"{self.where}: {self.words(exc)}") from None
        except StoreError:
            self.db.close()
            raise

    def sql(self, statement: str) -> str:
        return statement.replace("?", "%s")

    @contextlib.contextmanager
    def transaction(self, db: Any) -> Iterator[None]:
        with db.transaction():
            yield

    def before_write(self, db: Any, times: Iterable[int]) -> None:
        """The month partitions these instants fall in, created if missing (each in its
        own short transaction, before the batch's)."""
        for year, month in sorted({month_of(t) for t in times}):
            suffix = f"{year:04d}_{month:02d}"
            if suffix in self._partitions:
                continue
            low, high = month_bounds(year, month)
            with db.transaction():
                db.execute("SELECT pg_advisory_xact_lock(727101)")
                for table in PARTITIONED:
                    db.execute(f"CREATE TABLE IF NOT EXISTS {table}_{suffix} PARTITION OF "
                               f"{table} FOR VALUES FROM ({low}) TO ({high})")
            self._partitions.add(suffix)

    def after_delete(self, db: Any, cutoff_us: int) -> None:
        """Drop the month partitions wholly before the cutoff that no cell uses any more."""
        for table in PARTITIONED:
            rows = db.execute(
                "SELECT c.relname, pg_get_expr(c.relpartbound, c.oid) FROM pg_inherits i "
                "JOIN pg_class c ON c.oid = i.inhrelid WHERE i.inhparent = %s::regclass",
                (table,)).fetchall()
            for name, bound in rows:
                high = _upper_bound(bound)
                if high is None or high > cutoff_us:
                    continue
                with db.transaction():
                    if db.execute(f"SELECT 1 FROM {name} LIMIT 1").fetchone() is None:
                        db.execute(f"DROP TABLE {name}")
                        self._partitions.discard(name[len(table) + 1:])

    bucket_sql = ("SELECT c, count(*), min(value), max(value), "
                  "(array_agg(value ORDER BY t DESC))[1] FROM ("
                  "SELECT ((t - ?::bigint) * ?::bigint + ?::bigint - 1) / ?::bigint - 1 AS c, "
                  "t, value FROM plchmi_samples WHERE signal = ? AND t > ? AND t <= ?) s "
                  "GROUP BY c ORDER BY c")

    def words(self, exc: Exception) -> str:
        text = " ".join(str(exc).split())
        if "No space left" in text or "could not extend file" in text:
            return f"the database server's disk is full ({text})"
        return text or type(exc).__name__


def _upper_bound(bound: str) -> int | None:
    """The TO of "FOR VALUES FROM ('a') TO ('b')"."""
    try:
        return int(bound.rsplit("TO (", 1)[1].strip("') "))
    except (IndexError, ValueError):
        return None
