"""The historian: what a cell did, kept for days, read back as trends, CSV and OPC UA history.

    catalogue.py   what is recorded: every signal of a project (I/O, FOV, violations, the
                   diagnosers' states, the monitors' stopwatches, the cell's mode and scan
                   time, each device's travel times and operations), how it is stored
    recorder.py    the scan listener: change and deadband checks on the scan thread, the
                   samples into a bounded queue, never a wait
    writer.py      the writer thread: batches into the store, retention, and an alarm (never
                   a stop) when the store cannot be written
    store.py       the store interface and what a query returns
    sql.py         the schema's statements, shared by both stores
    sqlite.py      the embedded store (standard library, WAL), one file per cell
    postgres.py    PostgreSQL (psycopg 3), samples and events partitioned by month
    target.py      where a history is kept (--historian TARGET), and a connection to it
    query.py       reading: series over a window, values at an instant, per-column buckets,
                   the CSV export
    historian.py   Historian: the three together, attached to a Session
    span.py        durations and instants as an operator writes them (90d, 2h, an ISO time)

docs/history.md describes it for operators and engineers.
"""
