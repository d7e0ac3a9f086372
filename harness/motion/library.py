"""The capture library: humanoid56 trajectories retargeted from capture sets, kept in the repository so that the
evaluation plays back real people on a machine without the captures' source files.

``build_library(sources, out)`` retargets every row of each source set (``captures.retarget_rows``, each BVH row
with its own joint mapping) at ``LIBRARY_FPS``, refuses the build when a row misses the retargeting limits, and
writes, per set, a directory named like the source (``captures/cmu``, ``captures/bandai``) holding one ``npz``
motion per row (single precision, compressed), a manifest of ``npz`` rows with the source's columns (subject,
class, style, ...) and where each row came from, the set's terms of use (``TERMS.md``) and the licence files the
source ships. The library is itself a capture set: scenarios name it like any other (``docs/captures.md``).
``check_library`` verifies a built library without the sources: every row's file is there and loads, nothing
else is, each set has its terms, and the whole stays within ``MAX_LIBRARY_BYTES``.
"""

from __future__ import annotations

import csv
import io
import shutil
import tempfile
from pathlib import Path

import numpy as np

from harness.body import BodyModel
from harness.io import write_text_atomic
from harness.motion.captures import (MANIFEST_NAME, CaptureSetError, check_rows, quality_table, read_manifest,
                                     retarget_rows, row_motions)

LIBRARY_FPS = 30.0
MAX_LIBRARY_BYTES = 15 * 2**20
TERMS_NAME = "TERMS.md"
COLUMNS = ("file", "format", "skeleton", "subject", "trial", "class", "start", "end", "fps", "style",
           "source_file", "source_start", "source_end", "residual_mean_cm", "residual_max_cm")
#: Terms of the capture sets the project develops on, by set name (a set of another name brings its own
#: ``TERMS.md`` beside its manifest). Each states the source, its licence, the attribution it asks for, and what
#: was changed (CC BY asks that changes be indicated).
KNOWN_TERMS = {
    "cmu": """# Terms: the `cmu` capture set

Humanoid56 trajectories retargeted (inverse kinematics on joint positions, 30 frames per second, single
precision) from motions of the Carnegie Mellon University Graphics Lab Motion Capture Database
(http://mocap.cs.cmu.edu), as labelled in this project's development set (`../shared/mocap/cmu`; each row's
source file and frame range are in `MANIFEST.csv`).

The database may be used freely in research and commercial projects. It asks that publications acknowledge:
"The data used in this project was obtained from mocap.cs.cmu.edu. The database was created with funding from
NSF EIA-0196217."
""",
    "bandai": """# Terms: the `bandai` capture set

Humanoid56 trajectories retargeted (inverse kinematics on joint positions through the joint mapping of the
source set, 30 frames per second, single precision) from the Bandai Namco Research Motion Dataset (datasets 1
and 2, https://github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset), as labelled in this
project's development set (`../shared/mocap/bandai`; each row's source file and frame range are in
`MANIFEST.csv`). Changed: retargeted to another skeleton and resampled; the labels (class, style) are this
project's reading of the dataset's content and style names.

Licence: Creative Commons Attribution-NonCommercial 4.0 International (CC BY-NC 4.0; the dataset's licence
files are beside this one): use with attribution, no commercial use. Cite: M. Kobayashi, C.-C. Liao, K. Inoue,
S. Yojima, M. Takahashi, "Motion Capture Dataset for Practical Use of AI-based Motion Editing and Stylization",
arXiv:2306.08861, 2023.
""",
}


class LibraryError(CaptureSetError):
    """A library that cannot be built (a row beyond the retargeting limits, no terms, too large) or that fails
    its check."""


def _terms(source: Path) -> str:
    own = source / TERMS_NAME
    if own.is_file():
        return own.read_text()
    if source.name in KNOWN_TERMS:
        return KNOWN_TERMS[source.name]
    raise LibraryError(f"{source}: no terms of use for set {source.name!r}: put a {TERMS_NAME} beside its manifest "
                       f"(the source, its licence, the attribution it asks for)")


def _build_set(source: Path, out: Path, body: BodyModel, progress=None) -> list[dict]:
    """Retarget one source set into ``out`` (a new directory); returns its rows' quality."""
    rows = read_manifest(source / MANIFEST_NAME)
    check_rows(source, rows)
    terms = _terms(source)
    results = retarget_rows(source, rows, LIBRARY_FPS, body)
    quality = quality_table(rows, results)
    misses = [f"row {q['row']} ({q['file']})" for q in quality if not q["within_limits"]]
    if misses:
        raise LibraryError(f"{source}: rows beyond the retargeting limits, not put in the library: {', '.join(misses)}")
    out.mkdir(parents=True)
    table = []
    for row, (motion, _), q in zip(rows, results, quality):
        name = f"{row.line:03d}_{Path(row.file).stem}_{row.start}-{row.end}.npz"
        motion.save(out / name, dtype=np.float32, compressed=True)
        table.append({"file": name, "format": "npz", "skeleton": "", "subject": row.subject, "trial": row.trial,
                      "class": row.label, "start": 0, "end": motion.n_frames, "fps": LIBRARY_FPS,
                      "style": row.style, "source_file": row.file, "source_start": row.start,
                      "source_end": row.end, "residual_mean_cm": q["mean_cm"], "residual_max_cm": q["max_cm"]})
        if progress is not None:
            progress(1)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
    writer.writeheader()
    writer.writerows(table)
    write_text_atomic(out / MANIFEST_NAME, buf.getvalue())
    write_text_atomic(out / TERMS_NAME, terms)
    for licence in sorted(source.glob("LICENSE*")):
        shutil.copyfile(licence, out / licence.name)
    return quality


def build_library(sources: list[str | Path], out: str | Path, body: BodyModel | None = None,
                  progress=None) -> dict[str, list[dict]]:
    """Build the library of ``sources`` (capture set directories) under ``out``, one directory per set (an
    existing one of the same name is replaced only once the new one is built and checked). Returns each set's
    quality rows."""
    body = body or BodyModel.load()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = [Path(s).resolve().name for s in sources]
    if len(set(names)) != len(names):
        raise LibraryError(f"two sources share a name: {', '.join(names)} (a set is named by its directory)")
    quality = {}
    with tempfile.TemporaryDirectory(dir=out) as tmp:
        staged = Path(tmp)
        for source in map(Path, sources):
            quality[source.resolve().name] = _build_set(source.resolve(), staged / source.resolve().name, body,
                                                        progress)
        check_library(staged, names, extra=sum(_size(out / n) for n in library_names(out) if n not in names))
        for name in names:
            if (out / name).exists():
                shutil.rmtree(out / name)
            (staged / name).rename(out / name)
    return quality


def _size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) if path.exists() else 0


def library_names(library: str | Path) -> list[str]:
    """The sets of a library directory (each a directory with a manifest)."""
    library = Path(library)
    return sorted(d.name for d in library.iterdir() if (d / MANIFEST_NAME).is_file()) if library.is_dir() else []


def check_library(library: str | Path, names: list[str] | None = None, extra: int = 0) -> dict[str, int]:
    """Check a built library (module docstring); returns the rows per set. ``extra``: bytes of other sets
    counted against ``MAX_LIBRARY_BYTES``."""
    library = Path(library)
    names = library_names(library) if names is None else names
    if not names:
        raise LibraryError(f"{library}: no capture set (a directory with a {MANIFEST_NAME})")
    out = {}
    for name in names:
        directory = library / name
        rows = read_manifest(directory / MANIFEST_NAME, name=name)
        if any(r.format != "npz" for r in rows):
            raise LibraryError(f"{directory}: a library's rows are npz motions")
        if not (directory / TERMS_NAME).is_file():
            raise LibraryError(f"{directory}: no {TERMS_NAME} (the set's terms of use)")
        listed = {r.file for r in rows}
        stray = sorted(f.name for f in directory.glob("*.npz") if f.name not in listed)
        if stray:
            raise LibraryError(f"{directory}: files no manifest row names: {', '.join(stray[:3])}")
        motions = row_motions(directory, rows, LIBRARY_FPS)
        for row, motion in zip(rows, motions):
            if motion.n_frames != row.end - row.start or not np.isfinite(motion.qpos).all():
                raise LibraryError(f"{row.where('file')}: {row.file} does not hold the row's {row.end - row.start} "
                                   f"frames")
        out[name] = len(rows)
    total = sum(_size(library / n) for n in names) + extra
    if total > MAX_LIBRARY_BYTES:
        raise LibraryError(f"{library}: {total / 2**20:.1f} MB, more than {MAX_LIBRARY_BYTES / 2**20:g} MB")
    return out
