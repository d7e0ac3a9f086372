"""A build-once disk cache for expensive artefacts (motion databases), safe under parallel runs.

The artefact's path is a stable hash of its configuration (a JSON-able mapping), so equal configurations share
one file whatever order the runs come in; a lock file serialises the build, so that with ``--jobs N`` the
first run builds and the others wait and load. Writes are atomic (``harness.io.write_atomic``): an interrupted
build leaves no file and is simply rebuilt next time.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any, TypeVar

from harness.io import FileWriteError, write_atomic, write_text_atomic

T = TypeVar("T")


def stable_hash(key: Any) -> str:
    """sha256 (hex, 20 digits) of a JSON-able value, with mapping keys sorted; equal content, equal hash."""
    text = json.dumps(key, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def path_for_key(root: str | Path, key: dict, suffix: str = ".npz") -> Path:
    """``root/<hash of key><suffix>``; the key itself is written beside it (``.json``) for people to read."""
    root = Path(root)
    path = root / f"{stable_hash(key)}{suffix}"
    meta = path.with_suffix(".json")
    if not meta.exists():
        write_text_atomic(meta, json.dumps(key, sort_keys=True, indent=2) + "\n")
    return path


def cached(path: str | Path, build: Callable[[], T], save: Callable[[T, IO[bytes]], None],
           load: Callable[[Path], T]) -> T:
    """Load ``path`` if present; else ``build()``, ``save(obj, fh)`` atomically to ``path``, and return it.

    Holds an exclusive lock on ``path.lock`` while checking and building, so concurrent processes build once.
    """
    path = Path(path)
    lock_path = path.with_name(path.name + ".lock")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(lock_path, "a")
    except OSError as exc:          # full disk, read-only, a file in the way: one line naming it
        raise FileWriteError(f"{lock_path}: cannot write ({exc.strerror or type(exc).__name__})") from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if path.exists():
                return load(path)
            obj = build()
            write_atomic(path, lambda fh: save(obj, fh))
            return obj
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
