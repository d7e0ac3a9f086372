"""Capture sets: a directory of BVH / ASF-AMC files plus a manifest CSV -> labelled humanoid56 ``Motion``s.

Manifest format (``docs/captures.md``): one row per demonstration, columns ``file, format, skeleton,
subject, trial, class, start, end, fps`` (further columns such as ``description`` are kept out of the way).
``start``/``end`` index the frames as stored in the file, 0-based, end exclusive; a row that should skip a
BVH reference pose simply starts at 1. BVH rows take their frame rate from the file's ``Frame Time``,
AMC rows (which carry none) from ``fps``.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.body import BodyModel
from harness.errors import HarnessError
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


def read_manifest(path: str | Path, classes: list[str] | tuple[str, ...] | None = None) -> list[CaptureRow]:
    """Parse a manifest CSV. ``classes``: when given, a row whose class is not among them is an error."""
    path = Path(path)
    if not path.is_file():
        raise CaptureSetError(f"{path}: no such manifest file")
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        header = reader.fieldnames or []
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise CaptureSetError(f"{path}: missing columns {', '.join(missing)} (header: {', '.join(header)})")
        rows = []
        for raw in reader:
            line = reader.line_num
            where = lambda col: f"{path}: row {line}, column {col!r}"  # noqa: E731
            fmt = raw["format"].strip().lower()
            if fmt not in FORMATS:
                raise CaptureSetError(f"{where('format')}: unknown format {raw['format']!r} (formats: "
                                      f"{', '.join(FORMATS)})")
            values = {}
            for col, kind in (("start", int), ("end", int), ("fps", float)):
                try:
                    values[col] = kind(raw[col])
                except (TypeError, ValueError):
                    raise CaptureSetError(f"{where(col)}: not a number: {raw[col]!r}") from None
            if not 0 <= values["start"] < values["end"]:
                raise CaptureSetError(f"{where('start')}: frame range [{values['start']}, {values['end']}) is empty "
                                      f"or negative")
            if not values["fps"] > 0:
                raise CaptureSetError(f"{where('fps')}: must be positive, got {raw['fps']!r}")
            label = raw["class"].strip()
            if classes is not None and label not in classes:
                raise CaptureSetError(f"{where('class')}: unknown class {label!r} (classes: {', '.join(classes)})")
            if fmt == "amc" and not (raw["skeleton"] or "").strip():
                raise CaptureSetError(f"{where('skeleton')}: an amc row needs its ASF skeleton file")
            rows.append(CaptureRow(manifest=path, line=line, file=raw["file"].strip(), format=fmt,
                                   skeleton=(raw["skeleton"] or "").strip(), subject=raw["subject"].strip(),
                                   trial=raw["trial"].strip(), label=label, start=values["start"],
                                   end=values["end"], fps=values["fps"]))
    return rows


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
