"""Crash reports: the traceback of an error nobody expected, written where the operator can
find it and a developer can read it, so that the message on screen can stay short."""

from __future__ import annotations

import itertools
import os
import traceback
from datetime import UTC, datetime

from hmi.paths import data_folder

_counter = itertools.count(1)


def write_crash_report(exc: BaseException, what: str = "") -> str:
    """Write the traceback to the data folder; return its path (or why it could not).

    Each report gets its own file (time stamp, process id and a counter): two errors in
    the same second must not overwrite each other."""
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    path = data_folder() / f"crash-{stamp}-{os.getpid()}-{next(_counter)}.txt"
    head = f"{what}\n\n" if what else ""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(head + "".join(traceback.format_exception(exc)), encoding="utf-8")
    except OSError as err:
        return f"(no report: {err.strerror})"
    return str(path)
