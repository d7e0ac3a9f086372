"""The code version that results depend on: the package version plus a hash of the harness sources and the
tables and models shipped with them (``*.json``: the performer's calibration, the database's human floor;
``*.npz``: the bottom-up posture estimator).

It is part of every scenario hash and database cache key, so that runs and databases made by other code are
recognised as stale instead of being mixed with new ones. Modules that only read and format stored results
(``RESULTS_ONLY``) are left out, so that re-making a report after changing a plot keeps the stored runs.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

import harness

PACKAGE_DIR = Path(harness.__file__).resolve().parent
RESULTS_ONLY = ("evaluation/tables.py", "evaluation/plots.py", "evaluation/report.py", "evaluation/stats.py",
                "evaluation/regress.py", "evaluation/run_video.py", "evaluation/calibration.py")


@lru_cache(maxsize=1)
def code_version() -> str:
    """``<package version>+<first 12 hex digits of the SHA-256 over the sources and tables>`` (paths and
    contents, sorted)."""
    digest = hashlib.sha256()
    for path in sorted([*PACKAGE_DIR.rglob("*.py"), *PACKAGE_DIR.rglob("*.json"), *PACKAGE_DIR.rglob("*.npz")]):
        rel = path.relative_to(PACKAGE_DIR).as_posix()
        if rel in RESULTS_ONLY:
            continue
        digest.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
    return f"{harness.__version__}+{digest.hexdigest()[:12]}"
