"""Capture sets: a directory of BVH / ASF-AMC files plus a manifest CSV -> labelled humanoid56 ``Motion``s.

Manifest format (``docs/captures.md``): one row per demonstration, columns ``file, format, skeleton,
subject, trial, class, start, end, fps`` (further columns such as ``description`` are kept out of the way).
``start``/``end`` index the frames as stored in the file, 0-based, end exclusive; a row that should skip a
BVH reference pose simply starts at 1. BVH rows take their frame rate from the file's ``Frame Time``,
AMC rows (which carry none) from ``fps``.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from harness.body import BodyModel
from harness.errors import HarnessError
from harness.io import read_text
from harness.motion.asf_amc import asf_forward_kinematics, joint_names, load_amc, load_asf
from harness.motion.bvh import CMU_BVH_UNIT_M, load_bvh
from harness.motion.motion import Motion
from harness.motion.retarget import RetargetResult, retarget

MANIFEST_NAME = "MANIFEST.csv"
REQUIRED_COLUMNS = ("file", "format", "skeleton", "subject", "trial", "class", "start", "end", "fps")
FORMATS = ("bvh", "amc")


class CaptureSetError(HarnessError):
    """A manifest or capture that cannot be turned into motions; names the file, row and column."""


@dataclass(frozen=True)
class CaptureRow:
    """One manifest row. ``line``: its line in the manifest (the header is line 1)."""

    manifest: Path
    line: int
    file: str
    format: str
    skeleton: str
    subject: str
    trial: str
    label: str
    start: int
    end: int
    fps: float

    def where(self, column: str) -> str:
        return f"{self.manifest}: row {self.line}, column {column!r}"

    @property
    def demo(self) -> str:
        """An id unique per row: file stem and frame range."""
        return f"{Path(self.file).stem}:{self.start}-{self.end}"

    @property
    def source(self) -> str:
        return f"{self.format}:{self.file}[{self.start}:{self.end}]"


def _cell(value: str | None, limit: int = 40) -> str:
    """A manifest cell for an error message, shortened."""
    text = repr(value or "")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _relative(value: str, where: str) -> str:
    """A file column: a relative path that stays inside the capture directory (no absolute path, no ``..``)."""
    path = PurePosixPath(value.replace("\\", "/"))
    if not value or path.is_absolute() or PureWindowsPath(value).is_absolute() or ".." in path.parts:
        raise CaptureSetError(f"{where}: {_cell(value)} must be a path relative to the capture directory, "
                              f"without '..'")
    return value


def read_manifest(path: str | Path, classes: list[str] | tuple[str, ...] | None = None) -> list[CaptureRow]:
    """Parse a manifest CSV (at least one row). ``classes``: when given, a row whose class is not among them is
    an error. File columns must stay inside the capture directory."""
    path = Path(path)
    if not path.is_file():
        raise CaptureSetError(f"{path}: no such manifest file")
    text = read_text(path, CaptureSetError, "manifest")
    if "\x00" in text:
        raise CaptureSetError(f"{path}: not a CSV text file (it contains NUL bytes)")
    reader = csv.DictReader(io.StringIO(text, newline=""))
    try:
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise CaptureSetError(f"{path}: not a manifest: missing columns {', '.join(missing)} "
                                  f"(docs/captures.md)")
        reader.fieldnames = header
        rows = []
        for raw in reader:
            line = reader.line_num
            where = lambda col: f"{path}: row {line}, column {col!r}"  # noqa: E731
            if any(raw.get(c) is None for c in REQUIRED_COLUMNS):
                raise CaptureSetError(f"{path}: row {line}: {len([v for v in raw.values() if v is not None])} "
                                      f"cells, the header has {len(header)}")
            fmt = raw["format"].strip().lower()
            if fmt not in FORMATS:
                raise CaptureSetError(f"{where('format')}: unknown format {_cell(raw['format'])} (formats: "
                                      f"{', '.join(FORMATS)})")
            values = {}
            for col, kind in (("start", int), ("end", int), ("fps", float)):
                try:
                    values[col] = kind(raw[col])
                except (TypeError, ValueError):
                    raise CaptureSetError(f"{where(col)}: not a number: {_cell(raw[col])}") from None
            if not 0 <= values["start"] < values["end"]:
                raise CaptureSetError(f"{where('start')}: frame range [{values['start']}, {values['end']}) is empty "
                                      f"or negative")
            if not (math.isfinite(values["fps"]) and values["fps"] > 0):
                raise CaptureSetError(f"{where('fps')}: must be a positive number, got {_cell(raw['fps'])}")
            label = raw["class"].strip()
            if not label:
                raise CaptureSetError(f"{where('class')}: empty")
            if classes is not None and label not in classes:
                raise CaptureSetError(f"{where('class')}: unknown class {_cell(label)} (classes: {', '.join(classes)})")
            if not raw["subject"].strip():
                raise CaptureSetError(f"{where('subject')}: empty")
            skeleton = (raw["skeleton"] or "").strip()
            if fmt == "amc" and not skeleton:
                raise CaptureSetError(f"{where('skeleton')}: an amc row needs its ASF skeleton file")
            if skeleton:
                _relative(skeleton, where("skeleton"))
            rows.append(CaptureRow(manifest=path, line=line, file=_relative(raw["file"].strip(), where("file")),
                                   format=fmt, skeleton=skeleton, subject=raw["subject"].strip(),
                                   trial=raw["trial"].strip(), label=label, start=values["start"],
                                   end=values["end"], fps=values["fps"]))
    except csv.Error as exc:
        raise CaptureSetError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None
    if not rows:
        raise CaptureSetError(f"{path}: the manifest has a header but no rows")
    return rows


def demos_by_class(rows: list[CaptureRow]) -> dict[str, list[int]]:
    """The positions in ``rows`` of each class's demonstrations, in manifest order: demonstration ``d`` of
    class ``c`` (a run's ``test_demo``) is ``rows[demos_by_class(rows)[c][d]]``. The one numbering the runner
    plans with and the pipeline loads by."""
    out: dict[str, list[int]] = {}
    for i, row in enumerate(rows):
        out.setdefault(row.label, []).append(i)
    return out


class _SourceCache:
    """Parsed files of one capture set, so that a take cut into many rows is read once."""

    def __init__(self, directory: Path):
        self.directory = directory
        self.files: dict[tuple[str, str], object] = {}

    def _path(self, row: CaptureRow, name: str, column: str) -> Path:
        path = self.directory / name
        if not path.is_file():
            raise CaptureSetError(f"{row.where(column)}: no such file {path}")
        return path

    def positions(self, row: CaptureRow) -> tuple[np.ndarray, tuple[str, ...], float, float]:
        """Source joint positions ``(end - start, J, 3)`` in file units, joint names, fps, metres per unit."""
        if row.format == "bvh":
            key = ("bvh", row.file)
            if key not in self.files:
                self.files[key] = load_bvh(self._path(row, row.file, "file"))
            clip = self.files[key]
            self._check_range(row, clip.n_frames)
            return clip.positions(row.start, row.end), clip.names, clip.fps, CMU_BVH_UNIT_M
        skey = ("asf", row.skeleton)
        if skey not in self.files:
            self.files[skey] = load_asf(self._path(row, row.skeleton, "skeleton"))
        skeleton = self.files[skey]
        key = ("amc", row.file, row.skeleton)
        if key not in self.files:
            self.files[key] = load_amc(self._path(row, row.file, "file"), skeleton)
        amc = self.files[key]
        self._check_range(row, amc.n_frames)
        return (asf_forward_kinematics(skeleton, amc, row.start, row.end), joint_names(skeleton), row.fps,
                skeleton.unit_m)

    @staticmethod
    def _check_range(row: CaptureRow, n_frames: int) -> None:
        if row.end > n_frames:
            raise CaptureSetError(f"{row.where('end')}: frame range [{row.start}, {row.end}) goes beyond the "
                                  f"{n_frames} frames of {row.file}")


def retarget_rows(directory: str | Path, rows: list[CaptureRow], fps: float = 30.0,
                  body: BodyModel | None = None, mapping: dict[str, str | None] | None = None
                  ) -> list[tuple[Motion, RetargetResult]]:
    """Retarget each manifest row; returns the labelled motion and the retargeting details per row."""
    body = body or BodyModel.load()
    cache = _SourceCache(Path(directory))
    out = []
    for row in rows:
        positions, names, src_fps, unit_m = cache.positions(row)
        result = retarget(positions, names, src_fps, unit_m=unit_m, up="y", fps_out=fps, mapping=mapping,
                          body=body, where=f"{row.where('file')} ({row.file})")
        motion = Motion(qpos=result.qpos, fps=result.fps, label=row.label, subject=row.subject, demo=row.demo,
                        source=row.source)
        out.append((motion, result))
    return out


def load_capture_set(directory: str | Path, manifest: str | Path | None = None, fps: float = 30.0,
                     classes: list[str] | tuple[str, ...] | None = None, body: BodyModel | None = None,
                     mapping: dict[str, str | None] | None = None) -> list[Motion]:
    """One humanoid56 ``Motion`` per manifest row (``manifest`` defaults to ``directory/MANIFEST.csv``),
    cut to the row's frame range and retargeted at ``fps``; label = class, subject = subject id, demo = an
    id unique per row, source = format, file and range."""
    directory = Path(directory)
    if not directory.is_dir():
        raise CaptureSetError(f"{directory}: no such capture directory")
    rows = read_manifest(Path(manifest) if manifest is not None else directory / MANIFEST_NAME, classes)
    return [m for m, _ in retarget_rows(directory, rows, fps, body, mapping)]
