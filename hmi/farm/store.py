"""Each finished shard's result on disk, so a study stopped half-way is resumed.

A study's results live in one folder named by its kind, project and fingerprint, in the data
folder (``$PLCHMI_DATA/studies/``) or a folder given with ``--resume DIR``: one JSON file per
shard, written whole (a temporary file renamed), with the time it took (wall and CPU) and
where. Only a
file whose fingerprint matches is read back, and a damaged one is computed again. Files hold
plain JSON, never code (pickle would run whatever a file says).
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hmi.farm.job import Job


def default_root() -> Path:
    from hmi.paths import data_folder
    return data_folder() / "studies"


@dataclass(frozen=True)
class Kept:
    data: Any  # the study's JSON form of the shard's result
    seconds: float
    cpu: float | None  # None in a file of an older plchmi
    worker: str


KEPT_STUDIES = 5  # in the data folder, per kind of study and project: the latest ones


class ShardStore:
    def __init__(self, root: Path, job: Job, title: str, shards: int, prune: bool = False):
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in job.bundle.name)
        self.prefix = f"{job.kind}-{safe}-"
        self.folder = root / f"{self.prefix}{job.fingerprint[:16]}"
        self.fingerprint = job.fingerprint
        self.title = title
        self.shards = shards
        self.prune = prune

    def start(self, resume: bool) -> None:
        """Ready the folder: emptied unless resuming (a fresh run never mixes in old
        results), with a note of what it holds. In the data folder, the results of older
        studies of the same kind and project go beyond the latest KEPT_STUDIES (each edit of
        the project or the code makes a new fingerprint: they would pile up)."""
        if not resume and self.folder.exists():
            shutil.rmtree(self.folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        if self.prune:
            others = sorted((p for p in self.folder.parent.glob(f"{self.prefix}*")
                             if p != self.folder and p.is_dir()),
                            key=lambda p: p.stat().st_mtime, reverse=True)
            for old in others[KEPT_STUDIES - 1:]:
                shutil.rmtree(old, ignore_errors=True)
        self._write(self.folder / "study.json", {
            "title": self.title, "fingerprint": self.fingerprint, "shards": self.shards})

    def load(self, index: int) -> Kept | None:
        try:
            data = json.loads((self.folder / f"shard-{index:06d}.json").read_text("utf-8"))
            if data["fingerprint"] != self.fingerprint or data["index"] != index:
                return None
            cpu = data.get("cpu")
            return Kept(data["result"], float(data["seconds"]),
                        None if cpu is None else float(cpu), str(data["worker"]))
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def save(self, index: int, data: Any, seconds: float, cpu: float, worker: str) -> None:
        self._write(self.folder / f"shard-{index:06d}.json", {
            "fingerprint": self.fingerprint, "index": index, "seconds": round(seconds, 6),
            "cpu": round(cpu, 6), "worker": worker, "result": data})

    def _write(self, path: Path, data: Any) -> None:
        tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
        tmp.write_text(json.dumps(data, separators=(",", ":")), encoding="utf-8")
        tmp.replace(path)
