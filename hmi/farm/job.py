"""What a study asks of its workers (a :class:`Job`) and how it is cut (a :class:`Study`).

A job holds everything a worker needs, as plain data that pickles: the project's files, the
options, the code version the worker must run, and two module-level functions named by
reference — ``setup(project, options)`` builds what the worker keeps between shards (a
loaded project, explorers with their fault-free prefix), ``work(state, shard)`` computes one
shard. The fingerprint hashes the project, the code version, the study's kind, its options
and its cut: two runs with the same fingerprint compute the same shards, so the results kept
by one (hmi/farm/store.py) serve the other.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from hmi.farm.bundle import Bundle
from hmi.farm.version import code_version


@dataclass(frozen=True)
class Job:
    kind: str  # "campaign", "sweep", "soak": names the results' folder
    bundle: Bundle
    setup: Callable[[Any, Any], Any]  # (project, options) -> the worker's state
    work: Callable[[Any, Any], Any]  # (state, shard) -> the shard's result
    options: Any  # plain data (JSON): what setup reads
    code: str  # the code version's digest every worker must have
    fingerprint: str


@dataclass(frozen=True)
class Study:
    """A job, its shards (plain data, in the order their results merge), how many runs each
    holds (for the progress), the results' form on disk (JSON, never code), and, when the
    study can tell, each shard's expected cost: the heaviest are sent first, so that the
    workers do not end waiting on one long shard sent last (results still merge in order)."""

    title: str  # "campaign --sweep of cispi_valve", for messages
    job: Job
    shards: tuple[Any, ...]
    runs: tuple[int, ...]
    encode: Callable[[Any], Any]  # a shard's result -> JSON data
    decode: Callable[[Any, Any], Any]  # (shard, JSON data) -> the shard's result
    costs: tuple[float, ...] | None = None  # expected seconds per shard; None: sent in order

    @property
    def total_runs(self) -> int:
        return sum(self.runs)


def make_job(kind: str, bundle: Bundle, setup: Callable[[Any, Any], Any],
             work: Callable[[Any, Any], Any], options: Any, shards: Sequence[Any]) -> Job:
    code = code_version()
    text = json.dumps([kind, code.release, code.digest, bundle.digest, options, list(shards)],
                      sort_keys=True, separators=(",", ":"))
    return Job(kind, bundle, setup, work, options, code.digest,
               hashlib.sha256(text.encode()).hexdigest())
