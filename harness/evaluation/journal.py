"""The run journal: ``results/<scenario>/runs.jsonl``, one line per finished run, appended and fsynced.

Each line is one JSON object ``{"key": run key, "hash": scenario hash, "rows": [one dict per method]}``
written with a single ``write`` and then ``fsync``, so a run is either fully recorded or not at all. A process
killed mid-write leaves a last line without its newline: ``read`` detects it, truncates it away, and that run is
simply done again. Lines stored under another scenario hash are stale (the scenario changed since they were
computed); ``Journal`` refuses them unless told to start fresh (``fresh=True``).

NaN is written as the JSON extension ``NaN`` (Python's ``json`` reads it back exactly); floats round-trip
bit-identically through ``repr``.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from harness.errors import HarnessError

JOURNAL_NAME = "runs.jsonl"


class ResultsError(HarnessError):
    """A results directory that cannot be used: stale runs, a corrupt journal, or another writer."""


def _plain(value: Any) -> Any:
    """numpy scalars to Python scalars, so that rows serialise and compare exactly."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and math.isnan(value):
        return float("nan")
    return value


def read(path: str | Path, repair: bool = True) -> list[dict]:
    """Records of a journal, in file order. A torn last line (no newline) is dropped, and cut from the file
    when ``repair``; a malformed complete line raises ``ResultsError`` naming the line."""
    path = Path(path)
    if not path.exists():
        return []
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end < len(data) and repair:
        with open(path, "r+b") as fh:
            fh.truncate(end)
            os.fsync(fh.fileno())
    records = []
    for i, line in enumerate(data[:end].splitlines()):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ResultsError(f"{path}: line {i + 1}: not a JSON record ({exc.msg}); move the file away to "
                               f"start again") from None
        if not isinstance(rec, dict) or not {"key", "hash", "rows"} <= rec.keys():
            raise ResultsError(f"{path}: line {i + 1}: a record needs keys 'key', 'hash', 'rows'")
        records.append(rec)
    return records


class Journal:
    """An open journal for one scenario hash: the finished runs, and ``append`` for new ones.

    Holds an exclusive lock (``runs.jsonl.lock``) while open, so two evaluations cannot write one directory.
    """

    def __init__(self, directory: str | Path, scenario_hash: str, fresh: bool = False):
        self.directory = Path(directory)
        self.path = self.directory / JOURNAL_NAME
        self.hash = scenario_hash
        self.directory.mkdir(parents=True, exist_ok=True)
        self._lock = open(self.directory / (JOURNAL_NAME + ".lock"), "a")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            raise ResultsError(f"{self.directory}: another evaluation is writing these results") from None
        try:
            records = read(self.path)
            stale = sorted({r["hash"] for r in records if r["hash"] != scenario_hash})
            if stale and not fresh:
                raise ResultsError(
                    f"{self.path}: holds {len(records)} runs of a different version of this scenario (hash "
                    f"{', '.join(stale)}; now {scenario_hash}); pass --fresh to set them aside, or --results DIR")
            if stale:
                self.path.rename(self.directory / f"runs.stale-{stale[0]}.jsonl")
                records = []
            self.records: dict[str, dict] = {}
            for r in records:
                self.records.setdefault(r["key"], r)   # a key recorded twice keeps its first result
        except BaseException:
            self.close()
            raise
        self._fh = open(self.path, "ab")

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if getattr(self, "_fh", None) is not None:
            self._fh.close()
            self._fh = None
        if self._lock is not None:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()
            self._lock = None

    def __contains__(self, key: str) -> bool:
        return key in self.records

    def append(self, key: str, rows: list[dict]) -> None:
        """Record one finished run durably (one write, flush, fsync)."""
        rec = {"key": key, "hash": self.hash, "rows": [{k: _plain(v) for k, v in row.items()} for row in rows]}
        line = json.dumps(rec, separators=(",", ":")) + "\n"
        self._fh.write(line.encode())
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.records[key] = rec
