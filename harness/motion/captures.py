"""Capture sets: a directory of capture files plus a manifest CSV -> labelled humanoid56 ``Motion``s.

Manifest format (``docs/captures.md``): one row per demonstration, columns ``file, format, skeleton,
subject, trial, class, start, end, fps`` and optionally ``style`` (further columns such as ``description`` are
kept out of the way). ``start``/``end`` index the frames as stored in the file, 0-based, end exclusive; a row
that should skip a BVH reference pose simply starts at 1. Formats: ``bvh`` (its frame rate from the file's
``Frame Time``; ``skeleton``, when given, names a joint-mapping file in the directory for a skeleton the
built-in tables do not know), ``amc`` (``skeleton`` names its ASF file; the rate is ``fps``) and ``npz`` (a
humanoid56 ``Motion`` file, already retargeted: the capture library's rows). A set's name is its directory's
name; every motion of a row keeps it as ``source``, with the row's subject, style and ``demo`` (the file's stem
and frame range).
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from harness.body import BodyModel
from harness.errors import HarnessError
from harness.io import MAX_TEXT_BYTES, check_input_file, read_text, write_text_atomic
from harness.motion.asf_amc import asf_forward_kinematics, joint_names, load_amc, load_asf
from harness.motion.bvh import CMU_BVH_UNIT_M, load_bvh
from harness.motion.motion import Motion
from harness.motion.retarget import RetargetResult, retarget
from harness.motion.skeletons import MAPPING_SUFFIXES, load_mapping

MANIFEST_NAME = "MANIFEST.csv"
REQUIRED_COLUMNS = ("file", "format", "skeleton", "subject", "trial", "class", "start", "end", "fps")
FORMATS = ("bvh", "amc", "npz")
OPTIONAL_COLUMNS = ("style",)
#: The class of rows that show none of the primitives (``../shared/mocap/bandai``'s raised hands): never a
#: database's class; such rows are open-set test motions.
NO_PRIMITIVE = "other"
#: Issue 14's limits on a row's scale-normalised residual over every frame and target (metres): mean,
#: 95th percentile, maximum. A row beyond them is imported with a ``CaptureQualityWarning``.
RESIDUAL_LIMITS = {"mean": 0.03, "p95": 0.08, "max": 0.15}
#: How many of a row's worst frames a quality table and a warning name.
WORST_FRAMES = 5
MAX_MANIFEST_BYTES = 16 * 2**20     # a manifest of a million rows is not one


class CaptureSetError(HarnessError):
    """A manifest or capture that cannot be turned into motions; names the file, row and column."""


class RangeError(CaptureSetError):
    """A frame range beyond the frames of its capture file."""


class CaptureQualityWarning(UserWarning):
    """A row imported with a retargeting residual beyond ``RESIDUAL_LIMITS``; names the row and frames."""


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
    style: str = ""
    set_name: str = ""

    def where(self, column: str) -> str:
        return f"{self.manifest}: row {self.line}, column {column!r}"

    @property
    def demo(self) -> str:
        """An id unique per row within its set: file stem and frame range."""
        return f"{Path(self.file).stem}:{self.start}-{self.end}"


def _cell(value: str | None, limit: int = 40) -> str:
    """A manifest cell for an error message, shortened."""
    text = repr(value or "")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def relative_path_problem(value: str) -> str | None:
    """What keeps ``value`` from naming a file inside a directory by its text alone (empty, absolute, with a
    ``..`` part or a NUL byte), or None. Symbolic links are checked on disk (``inside``)."""
    path = PurePosixPath(value.replace("\\", "/"))
    if not value or path.is_absolute() or PureWindowsPath(value).is_absolute() or ".." in path.parts \
            or "\x00" in value:
        return "must be a path relative to the capture directory, without '..'"
    return None


def _relative(value: str, where: str) -> str:
    """A file column: a relative path that stays inside the capture directory (no absolute path, no ``..``)."""
    if relative_path_problem(value):
        raise CaptureSetError(f"{where}: {_cell(value)} must be a path relative to the capture directory, "
                              f"without '..'")
    return value


def inside(directory: str | Path, relative: str, where: str) -> Path:
    """``directory / relative`` with symbolic links followed, refused (``CaptureSetError`` naming ``where``)
    unless it stays inside the directory (itself resolved) and is an existing regular file of at most
    ``MAX_TEXT_BYTES``: a symlink to a system file, or a symlinked folder to ``/``, is never read."""
    root = Path(directory).resolve()
    target = (root / relative).resolve()
    if not target.is_relative_to(root):
        raise CaptureSetError(f"{where}: {_cell(relative)} leads outside the capture directory {root} "
                              f"(a symbolic link)")
    if not target.exists():
        raise CaptureSetError(f"{where}: no such file {root / relative}")
    try:
        check_input_file(target, CaptureSetError, "capture", MAX_TEXT_BYTES)
    except CaptureSetError as exc:
        raise CaptureSetError(f"{where}: {exc}") from None
    return target


def check_rows(directory: str | Path, rows: list[CaptureRow]) -> None:
    """Every row's file (and skeleton) exists inside ``directory`` as a regular file (``inside``): checked
    before any row is read, so a bad row is refused before any work."""
    for row in rows:
        inside(directory, row.file, row.where("file"))
        if row.skeleton:
            inside(directory, row.skeleton, row.where("skeleton"))


def read_manifest(path: str | Path, classes: list[str] | tuple[str, ...] | None = None,
                  name: str | None = None) -> list[CaptureRow]:
    """Parse a manifest CSV (at least one row). ``classes``: when given, a row whose class is not among them is
    an error. File columns must stay inside the capture directory. ``name``: the set's name every row keeps
    (default: the name of the manifest's directory)."""
    path = Path(path)
    name = name or path.resolve().parent.name
    text = read_text(path, CaptureSetError, "manifest", MAX_MANIFEST_BYTES)
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
            if fmt == "bvh" and skeleton and Path(skeleton).suffix.lower() not in MAPPING_SUFFIXES:
                raise CaptureSetError(f"{where('skeleton')}: a bvh row's skeleton names a joint-mapping file "
                                      f"({', '.join(MAPPING_SUFFIXES)}), got {_cell(skeleton)}")
            if fmt == "npz" and skeleton:
                raise CaptureSetError(f"{where('skeleton')}: an npz row is a humanoid56 motion already, it takes "
                                      f"no skeleton (got {_cell(skeleton)})")
            if skeleton:
                _relative(skeleton, where("skeleton"))
            rows.append(CaptureRow(manifest=path, line=line, file=_relative(raw["file"].strip(), where("file")),
                                   format=fmt, skeleton=skeleton, subject=raw["subject"].strip(),
                                   trial=raw["trial"].strip(), label=label, start=values["start"],
                                   end=values["end"], fps=values["fps"], style=(raw.get("style") or "").strip(),
                                   set_name=name))
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


def file_positions(path: str | Path, skeleton: str | Path | None = None, start: int = 0, end: int | None = None,
                   fps: float | None = None, files: dict | None = None, fmt: str | None = None
                   ) -> tuple[np.ndarray, tuple[str, ...], float, float]:
    """Source joint positions of frames ``[start, end)`` of one capture file, ``(T, J, 3)`` in file units,
    with the joint names, the frame rate and the metres per file unit.

    ``fmt`` (``"bvh"`` or ``"amc"``, default: the file's suffix): for BVH the frame rate is the file's; for
    AMC ``skeleton`` is its ASF file and ``fps`` its rate (AMC files carry none). ``files``, when given, keeps
    parsed files by path so that a take cut into many rows is read once. Raises ``CaptureSetError`` for
    another format, an AMC without skeleton or fps, or a range beyond the file.
    """
    path = Path(path)
    files = {} if files is None else files
    fmt = fmt or path.suffix.lower().lstrip(".")
    if fmt == "bvh":
        if path not in files:
            files[path] = load_bvh(path)
        clip = files[path]
        _check_range(path, start, end, clip.n_frames)
        return clip.positions(start, end), clip.names, clip.fps, CMU_BVH_UNIT_M
    if fmt != "amc":
        raise CaptureSetError(f"{path}: capture files must be .bvh or .amc")
    if skeleton is None or fps is None:
        raise CaptureSetError(f"{path}: an .amc file needs its ASF skeleton and its frame rate")
    skeleton = Path(skeleton)
    if skeleton not in files:
        files[skeleton] = load_asf(skeleton)
    asf = files[skeleton]
    if (path, skeleton) not in files:
        files[(path, skeleton)] = load_amc(path, asf)
    amc = files[(path, skeleton)]
    _check_range(path, start, end, amc.n_frames)
    return asf_forward_kinematics(asf, amc, start, end), joint_names(asf), float(fps), asf.unit_m


def _check_range(path: Path, start: int, end: int | None, n_frames: int) -> None:
    stop = n_frames if end is None else end
    if not 0 <= start < stop <= n_frames:
        raise RangeError(f"frame range [{start}, {stop}) goes beyond the {n_frames} frames of {path.name}")


def _row_positions(directory: Path, row: CaptureRow, files: dict
                   ) -> tuple[np.ndarray, tuple[str, ...], float, float]:
    """``file_positions`` of a manifest row, with errors that name the row and column."""
    path = inside(directory, row.file, row.where("file"))
    skeleton = None
    if row.format == "amc":
        skeleton = inside(directory, row.skeleton, row.where("skeleton"))
    try:
        return file_positions(path, skeleton, row.start, row.end, row.fps, files, row.format)
    except RangeError as exc:
        raise CaptureSetError(f"{row.where('end')}: {exc}") from None


def row_mapping(directory: Path, row: CaptureRow, body: BodyModel, mappings: dict) -> dict | None:
    """The joint mapping a BVH row names in its ``skeleton`` column (a file inside the capture directory), or
    None (the built-in tables); ``mappings`` keeps files already read by path."""
    if row.format != "bvh" or not row.skeleton:
        return None
    path = inside(directory, row.skeleton, row.where("skeleton"))
    if path not in mappings:
        mappings[path] = load_mapping(path, body.body_names)
    return mappings[path]


def row_motion(row: CaptureRow, qpos: np.ndarray, fps: float) -> Motion:
    """The labelled motion of a row: its class, subject, style, set (``source``) and ``demo``."""
    return Motion(qpos=qpos, fps=fps, label=row.label, subject=row.subject, demo=row.demo, source=row.set_name,
                  style=row.style)


def retarget_rows(directory: str | Path, rows: list[CaptureRow], fps: float = 30.0,
                  body: BodyModel | None = None, mapping: dict[str, str | None] | None = None
                  ) -> list[tuple[Motion, RetargetResult]]:
    """Retarget each manifest row (``bvh`` and ``amc``); returns the labelled motion and the retargeting details
    per row. ``mapping``: one joint mapping for every row (a command line's ``--mapping``), instead of the one a
    BVH row names in its ``skeleton`` column and the built-in tables."""
    body = body or BodyModel.load()
    directory = Path(directory)
    files: dict = {}
    mappings: dict = {}
    out = []
    for row in rows:
        if row.format == "npz":
            raise CaptureSetError(f"{row.where('format')}: an npz row is retargeted already (row_motions loads it)")
        positions, names, src_fps, unit_m = _row_positions(directory, row, files)
        chosen = mapping if mapping is not None else row_mapping(directory, row, body, mappings)
        result = retarget(positions, names, src_fps, unit_m=unit_m, up="y", fps_out=fps, mapping=chosen,
                          body=body, where=f"{row.where('file')} ({row.file})")
        motion = row_motion(row, result.qpos, result.fps)
        quality = row_quality(row, result)
        if not quality["within_limits"]:
            warnings.warn(CaptureQualityWarning(
                f"{row.manifest}: row {row.line} ({row.file} [{row.start}, {row.end}), {row.label}): retargeting "
                f"residual mean {quality['mean_cm']:.1f} cm, p95 {quality['p95_cm']:.1f} cm, max "
                f"{quality['max_cm']:.1f} cm beyond the limits (3, 8, 15 cm); worst frames "
                f"{quality['worst_frames']} (at {result.fps:g} fps)"), stacklevel=2)
        out.append((motion, result))
    return out


def row_quality(row: CaptureRow, result: RetargetResult) -> dict:
    """One row of the retargeting quality table: the row, its residual statistics over every frame and target
    (cm), whether they are within ``RESIDUAL_LIMITS`` and the ``WORST_FRAMES`` frames with the largest
    residual (frame indices of the retargeted motion, worst first, space-separated)."""
    res = np.asarray(result.residual)
    stats = {"mean": float(res.mean()), "p95": float(np.percentile(res, 95)), "max": float(res.max())}
    worst = np.argsort(-res.max(axis=1), kind="stable")[:WORST_FRAMES]
    return {"row": row.line, "file": row.file, "start": row.start, "end": row.end, "class": row.label,
            "subject": row.subject, "frames": len(res), "fps": result.fps,
            **{f"{k}_cm": round(100.0 * v, 3) for k, v in stats.items()},
            "within_limits": all(stats[k] <= RESIDUAL_LIMITS[k] for k in RESIDUAL_LIMITS),
            "worst_frames": " ".join(str(int(t)) for t in worst)}


def quality_table(rows: list[CaptureRow], results: list[tuple[Motion, RetargetResult]]) -> list[dict]:
    """``row_quality`` of every retargeted row."""
    return [row_quality(row, result) for row, (_, result) in zip(rows, results)]


def write_quality_csv(path: str | Path, table: list[dict]) -> None:
    """Write a quality table (``quality_table``) as CSV with a header row, atomically."""
    if not table:
        raise CaptureSetError(f"{path}: no rows to write")
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(table[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(table)
    write_text_atomic(path, buf.getvalue())


def library_motion(directory: Path, row: CaptureRow, fps: float) -> Motion:
    """An ``npz`` row: frames ``[start, end)`` of a stored humanoid56 motion, at ``fps``."""
    path = inside(directory, row.file, row.where("file"))
    stored = Motion.load(path)
    _check_range(path, row.start, row.end, stored.n_frames)
    whole = (row.start, row.end) == (0, stored.n_frames)
    # The stored motion names the row it was retargeted from (``stem:start-end``): the same demo as the source's.
    motion = row_motion(row, stored.qpos[row.start:row.end], stored.fps).replace(
        demo=stored.demo if whole else f"{stored.demo}[{row.start}:{row.end}]")
    return motion if abs(motion.fps - fps) < 1e-9 else motion.resample(fps)


def row_motions(directory: str | Path, rows: list[CaptureRow], fps: float = 30.0, body: BodyModel | None = None,
                mapping: dict[str, str | None] | None = None) -> list[Motion]:
    """One humanoid56 ``Motion`` per row, in order: ``npz`` rows loaded, the others retargeted
    (``retarget_rows``)."""
    directory = Path(directory)
    raw = [row for row in rows if row.format != "npz"]
    retargeted = iter(m for m, _ in retarget_rows(directory, raw, fps, body, mapping)) if raw else iter(())
    return [library_motion(directory, row, fps) if row.format == "npz" else next(retargeted) for row in rows]


def load_capture_set(directory: str | Path, manifest: str | Path | None = None, fps: float = 30.0,
                     classes: list[str] | tuple[str, ...] | None = None, body: BodyModel | None = None,
                     mapping: dict[str, str | None] | None = None) -> list[Motion]:
    """One humanoid56 ``Motion`` per manifest row (``manifest`` defaults to ``directory/MANIFEST.csv``),
    cut to the row's frame range and retargeted (or loaded) at ``fps``; label = class, subject, style,
    source = the set's name, demo = an id unique per row in the set."""
    directory = Path(directory)
    if not directory.is_dir():
        raise CaptureSetError(f"{directory}: no such capture directory")
    rows = read_manifest(Path(manifest) if manifest is not None else directory / MANIFEST_NAME, classes,
                         name=directory.resolve().name)
    check_rows(directory, rows)
    return row_motions(directory, rows, fps, body, mapping)
