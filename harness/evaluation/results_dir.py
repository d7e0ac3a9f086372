"""A scenario's results directory, checked before anything is planned, trained or written.

``--results ROOT`` holds one directory per scenario (``ROOT/<name>``, the name one path component) and the
database cache (``ROOT/cache``). ``check`` refuses, with one line naming the path, what would otherwise fail
after the work (a traceback, or a run lost): a file where a directory must be, a directory (or FIFO, device)
where a file will be replaced, a scenario directory that leads outside ROOT through a symbolic link, a
directory that cannot be written (read-only file system, permissions), and a file system with less than
``MIN_FREE_BYTES`` free. A disk that fills up during the runs is a one-line error from the journal or from
the atomic writes (``harness.io.FileWriteError``), and the runs recorded before it are kept.
"""

from __future__ import annotations

import os
from pathlib import Path

from harness.evaluation.journal import JOURNAL_NAME, ResultsError
from harness.io import OutputPathError, check_output_dir

MIN_FREE_BYTES = 64 * 2**20     # a database (2 MB), the journal and the report's plots, with room to spare
# What the runner and the report write in a scenario's directory: files replaced atomically, directories.
FILES = (JOURNAL_NAME, JOURNAL_NAME + ".lock", "scenario.json", "runs.csv", "report.md", "metrics.json")
DIRECTORIES = ("plots", "plots/timelines")
CACHE_DIRECTORIES = ("databases",)


def check(results_dir: str | Path, cache_dir: str | Path | None = None) -> Path:
    """Refuse a results directory (``ROOT/<name>``) and cache directory that the evaluation could not use; see
    the module docstring. Creates nothing; returns ``results_dir``."""
    results_dir = Path(results_dir)
    root = results_dir.parent
    if results_dir.name in ("", ".", "..") or Path(results_dir.name).name != results_dir.name:
        raise ResultsError(f"{results_dir}: a scenario's results directory must be one name inside --results")
    try:
        check_output_dir(root, "--results")
        if results_dir.exists() or results_dir.is_symlink():
            _directory(results_dir)
            if not results_dir.resolve().is_relative_to(root.resolve()):
                raise ResultsError(f"{results_dir}: leads outside --results {root} (a symbolic link)")
            check_output_dir(results_dir, "--results")
            for name in FILES + tuple(f for f in _tables(results_dir)):
                _file(results_dir / name)
            for name in DIRECTORIES:
                if (results_dir / name).exists() or (results_dir / name).is_symlink():
                    _directory(results_dir / name)
        cache = Path(cache_dir) if cache_dir is not None else root / "cache"
        for path in (cache, *(cache / d for d in CACHE_DIRECTORIES)):
            if path.exists() or path.is_symlink():
                _directory(path)
                check_output_dir(path, "--results")
    except OutputPathError as exc:
        raise ResultsError(str(exc)) from None
    _free_space(root)
    return results_dir


def _tables(directory: Path) -> list[str]:
    """The table files already in a results directory (``*.csv``, ``*.md``): each must be a regular file."""
    try:
        return sorted(e.name for e in os.scandir(directory) if e.name.endswith((".csv", ".md")))
    except OSError as exc:
        raise ResultsError(f"{directory}: cannot be listed ({exc.strerror})") from None


def _directory(path: Path) -> None:
    if not path.is_dir():
        what = "a broken symbolic link" if path.is_symlink() and not path.exists() else "not a directory"
        raise ResultsError(f"{path}: is {what} (the evaluation writes a directory there)")


def _file(path: Path) -> None:
    if (path.exists() or path.is_symlink()) and not path.is_file():
        what = "a directory" if path.is_dir() else "not a regular file"
        raise ResultsError(f"{path}: is {what} (the evaluation writes a file there)")


def _free_space(root: Path) -> None:
    probe = root
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    try:
        st = os.statvfs(probe)
    except OSError:
        return
    free = st.f_bavail * st.f_frsize
    if free < MIN_FREE_BYTES:
        raise ResultsError(f"--results {root}: only {free // 2**20} MB free on its file system (at least "
                           f"{MIN_FREE_BYTES // 2**20} MB needed)")
