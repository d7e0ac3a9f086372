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
import itertools
import json
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from harness.errors import HarnessError
from harness.io import check_input_file

JOURNAL_NAME = "runs.jsonl"
MAX_JOURNAL_BYTES = 4 * 2**30      # 100,000 runs (the plan's limit) of five methods are about 2 GB
MAX_LINE_BYTES = 64 * 2**20        # one run's record (a stream's rows of every method are tens of kB)
# ``c000/r000/walk/d008``, or with a capture set's name ``c000/r000/cmu/walk/d008``; no '..' part
RUN_KEY = re.compile(r"^c\d{3,}/r\d{3,}/(?:(?!\.\.?/)[^/\x00]+/)?(?!\.\.?/)[^/\x00]+/d\d{3,}$")


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
    """Records of a journal, in file order (``records``, collected)."""
    return list(records(path, repair))


def records(path: str | Path, repair: bool = True) -> Iterator[dict]:
    """The records of a journal one at a time, in file order, read line by line (a journal of 100,000 runs is
    about 2 GB: never held whole). A torn last line (no newline) is dropped, and cut from the file when
    ``repair``, but only once every complete line has been read and found well formed: a journal that is
    refused (``ResultsError`` naming the line: not JSON, not a record, not a regular file, too large, a line
    over ``MAX_LINE_BYTES``) is never modified."""
    path = Path(path)
    if not os.path.lexists(path):
        return
    check_input_file(path, ResultsError, "journal", MAX_JOURNAL_BYTES)
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise ResultsError(f"{path}: cannot be read ({exc.strerror})") from None
    with fh:
        end = 0                   # the offset after the last complete line
        for i in itertools.count():
            try:
                line = fh.readline(MAX_LINE_BYTES + 1)
            except OSError as exc:
                raise ResultsError(f"{path}: cannot be read ({exc.strerror})") from None
            if not line:
                break
            if len(line) > MAX_LINE_BYTES:
                raise ResultsError(f"{path}: line {i + 1}: longer than {MAX_LINE_BYTES} bytes (not a run's record); "
                                   f"move the file away to start again")
            if not line.endswith(b"\n"):           # torn: a write cut short by a kill
                break
            if end + len(line) > MAX_JOURNAL_BYTES:
                raise ResultsError(f"{path}: too large for a journal file (at most {MAX_JOURNAL_BYTES} bytes)")
            end += len(line)
            if line.strip():
                yield _parse(path, i, line)
        torn = fh.seek(0, os.SEEK_END) > end
    if torn and repair:
        try:
            with open(path, "r+b") as out:
                out.truncate(end)
                os.fsync(out.fileno())
        except OSError as exc:
            raise ResultsError(f"{path}: cannot cut its torn last line ({exc.strerror})") from None


def _parse(path: Path, i: int, line: bytes) -> dict:
    """Line ``i`` (0-based) of a journal as a record; ``ResultsError`` naming the line otherwise."""
    try:
        rec = json.loads(line)
    except (ValueError, RecursionError) as exc:     # not JSON, not UTF-8, nested too deep, 5000 digits
        why = exc.msg if isinstance(exc, json.JSONDecodeError) else (
            "nested too deeply" if isinstance(exc, RecursionError) else "not UTF-8 text or a malformed number")
        raise ResultsError(f"{path}: line {i + 1}: not a JSON record ({why}); move the file away to "
                           f"start again") from None
    problem = _record_problem(rec)
    if problem:
        raise ResultsError(f"{path}: line {i + 1}: {problem}; move the file away to start again")
    return rec


def _record_problem(rec: Any) -> str | None:
    """What makes a parsed line not a journal record, or None."""
    if not isinstance(rec, dict) or not {"key", "hash", "rows"} <= rec.keys():
        return "a record needs keys 'key', 'hash', 'rows'"
    if not isinstance(rec["key"], str) or not RUN_KEY.match(rec["key"]):
        return "'key' must be a run key like c000/r000/walk/d008 or c000/r000/cmu/walk/d008"
    if not isinstance(rec["hash"], str):
        return "'hash' must be a string"
    if not isinstance(rec["rows"], list) or not all(isinstance(r, dict) for r in rec["rows"]):
        return "'rows' must be a list of mappings"
    return None


def _index(path: Path, repair: bool = True) -> tuple[list[str], set[str]]:
    """The run keys of a journal's records (file order) and their scenario hashes, streamed: what an open
    journal needs, without the rows."""
    keys, hashes = [], set()
    for rec in records(path, repair):
        keys.append(rec["key"])
        hashes.add(rec["hash"])
    return keys, hashes


class Journal:
    """An open journal for one scenario hash: the finished runs, and ``append`` for new ones.

    Holds an exclusive lock (``runs.jsonl.lock``) while open, so two evaluations cannot write one directory.
    A journal that is malformed or holds runs of another hash (without ``fresh``) is refused before the
    directory or the lock is created and before the journal is touched.
    """

    def __init__(self, directory: str | Path, scenario_hash: str, fresh: bool = False):
        self.directory = Path(directory)
        self.path = self.directory / JOURNAL_NAME
        self.hash = scenario_hash
        self._lock = self._fh = None
        lock_path = self.directory / (JOURNAL_NAME + ".lock")
        self._check_stale(*_index(self.path, repair=False), fresh)
        if os.path.lexists(lock_path) and not lock_path.is_file():
            raise ResultsError(f"{lock_path}: is not a regular file (the evaluation's lock)")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._lock = open(lock_path, "a")
        except OSError as exc:
            raise ResultsError(f"{lock_path}: cannot be created ({exc.strerror})") from None
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            self._lock = None
            raise ResultsError(f"{self.directory}: another evaluation is writing these results") from None
        try:
            keys, hashes = _index(self.path)   # again, under the lock: cuts a torn last line
            stale = self._check_stale(keys, hashes, fresh)
            if stale:
                self.path.rename(self.directory / f"runs.stale-{stale[0]}.jsonl")
                keys = []
            self.keys: set[str] = set(keys)        # the finished runs (a key recorded twice counts once)
            self._fh = open(self.path, "ab")
        except OSError as exc:
            self.close()
            raise ResultsError(f"{self.path}: cannot be opened for appending ({exc.strerror})") from None
        except BaseException:
            self.close()
            raise

    def _check_stale(self, keys: list[str], hashes: set[str], fresh: bool) -> list[str]:
        """The other hashes among the journal's ``hashes``; refused unless ``fresh``."""
        stale = sorted(hashes - {self.hash})
        if stale and not fresh:
            raise ResultsError(
                f"{self.path}: holds {len(keys)} runs of a different version of this scenario (hash "
                f"{', '.join(stale)}; now {self.hash}); pass --fresh to set them aside, or --results DIR")
        return stale

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if getattr(self, "_fh", None) is not None:
            try:
                self._fh.close()
            except OSError:        # a failed flush of the last append: that run is simply done again
                pass
            self._fh = None
        if self._lock is not None:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()
            self._lock = None

    def __contains__(self, key: str) -> bool:
        return key in self.keys

    def append(self, key: str, rows: list[dict]) -> None:
        """Record one finished run durably (one write, flush, fsync). A write the file system refuses (full
        disk, read-only) is a ``ResultsError``; the runs recorded before it are kept, and a partly written
        line is a torn last line that the next start cuts."""
        rec = {"key": key, "hash": self.hash, "rows": [{k: _plain(v) for k, v in row.items()} for row in rows]}
        line = json.dumps(rec, separators=(",", ":")) + "\n"
        try:
            self._fh.write(line.encode())
            self._fh.flush()
            os.fsync(self._fh.fileno())
        except OSError as exc:
            raise ResultsError(f"{self.path}: cannot record run {key} ({exc.strerror}); the runs recorded before "
                               f"it are kept, re-run to resume") from None
        self.keys.add(key)
