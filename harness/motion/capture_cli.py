"""Commands for captured motion: ``import-capture`` (a capture set to Motion files) and ``capture-video``
(a retargeted capture beside its source skeleton, to check the retargeting by eye)."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

from harness.commands import command
from harness.errors import HarnessError


def _import_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("directory", help="directory holding the capture files and (by default) MANIFEST.csv")
    p.add_argument("--manifest", default=None, help="manifest CSV (default: DIRECTORY/MANIFEST.csv)")
    p.add_argument("--out", default="captures", help="output directory for the Motion .npz files")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the retargeted motions")
    p.add_argument("--mapping", default=None, help="joint mapping file (YAML or CSV: source joint -> body) for every "
                                                   "row (default: each BVH row's skeleton column, else the built-in "
                                                   "tables)")
    p.add_argument("--classes", default=None, help="comma-separated allowed classes (others are an error)")
    p.add_argument("--report", default=None, help="also write the per-row retargeting quality table to this CSV")


def _manifest_rows(directory: Path, manifest: str | None, classes: list[str] | None = None):
    from harness.motion.captures import MANIFEST_NAME, read_manifest

    return read_manifest(Path(manifest) if manifest else directory / MANIFEST_NAME, classes)


@command("import-capture", _import_args)
def _import_capture(args: argparse.Namespace) -> int:
    """Retarget every row of a capture set to humanoid56 and write one Motion .npz per row.

    Rows whose residual exceeds the limits (``captures.RESIDUAL_LIMITS``) are written too, with a warning
    naming the row and its worst frames."""
    from harness.body import BodyModel
    from harness.io import check_output_dir, check_output_file
    from harness.motion.captures import (CaptureQualityWarning, check_rows, quality_table, retarget_rows,
                                         write_quality_csv)
    from harness.motion.skeletons import load_mapping

    body = BodyModel.load()
    directory = Path(args.directory)
    classes = [c.strip() for c in args.classes.split(",")] if args.classes else None
    rows = _manifest_rows(directory, args.manifest, classes)
    check_rows(directory, rows)
    out = check_output_dir(args.out)
    if args.report:
        check_output_file(args.report, "--report")
    mapping = load_mapping(args.mapping, body.body_names) if args.mapping else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CaptureQualityWarning)
        results = retarget_rows(directory, rows, args.fps, body, mapping)
    print(f"{'row':>4} {'file':14} {'class':12} {'frames':>6} {'mean cm':>8} {'p95 cm':>7} {'max cm':>7}  output")
    for row, (motion, _), quality in zip(rows, results, quality_table(rows, results)):
        name = f"{row.line:03d}_{Path(row.file).stem}_{row.start}-{row.end}_{row.label}.npz"
        motion.save(out / name)
        print(f"{row.line:>4} {row.file:14} {row.label:12} {motion.n_frames:>6} {quality['mean_cm']:8.2f} "
              f"{quality['p95_cm']:7.2f} {quality['max_cm']:7.2f}  {out / name}")
    for w in caught:
        if issubclass(w.category, CaptureQualityWarning):
            print(f"warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if args.report:
        write_quality_csv(args.report, quality_table(rows, results))
        print(f"quality table: {args.report}")
    return 0


def _video_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a .bvh or .amc file, or a manifest row number (the CSV line, header = 1)")
    p.add_argument("--out", required=True, help="video file (.mp4 or .gif)")
    p.add_argument("--dir", default=".", help="capture directory for a row number (default: .)")
    p.add_argument("--manifest", default=None, help="manifest CSV (default: DIR/MANIFEST.csv)")
    p.add_argument("--skeleton", default=None, help="ASF file for an .amc source")
    p.add_argument("--start", type=int, default=0, help="first frame of a file source")
    p.add_argument("--end", type=int, default=None, help="end frame (exclusive) of a file source")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the retargeted motion and video")
    p.add_argument("--source-fps", type=float, default=120.0, help="frame rate of an .amc file (default 120)")
    p.add_argument("--mapping", default=None, help="joint mapping file (YAML or CSV: source joint -> body) for a "
                                                   "skeleton the built-in tables do not know (a manifest row's own "
                                                   "skeleton column is used otherwise)")
    p.add_argument("--stills", type=int, default=0, help="also write this many evenly spaced PNG stills")
    p.add_argument("--worst-stills", type=int, default=0,
                   help="also write PNG stills of this many frames with the largest residual")
    p.add_argument("--size", type=int, default=480, help="frame width and height in pixels")


@command("capture-video", _video_args)
def _capture_video(args: argparse.Namespace) -> int:
    """Render a retargeted capture with the source skeleton's scaled joints drawn as spheres."""
    from harness.body import BodyModel
    from harness.io import check_output_file, write_atomic
    from harness.motion.captures import file_positions, retarget_rows
    from harness.motion.retarget import retarget
    from harness.motion.skeletons import load_mapping
    from harness.video import render_motion, write_video

    check_output_file(args.out)
    body = BodyModel.load()
    mapping = load_mapping(args.mapping, body.body_names) if args.mapping else None
    if args.source.isdigit():
        directory = Path(args.dir)
        rows = _manifest_rows(directory, args.manifest)
        chosen = [r for r in rows if r.line == int(args.source)]
        if not chosen:
            raise HarnessError(f"manifest has no row {args.source} (rows: {rows[0].line}-{rows[-1].line})")
        (_, result), = retarget_rows(directory, chosen, args.fps, body, mapping)
    else:
        path = Path(args.source)
        if not path.is_file():
            raise HarnessError(f"{path}: no such file (capture-video takes a .bvh or .amc file or a manifest row)")
        positions, names, fps, unit_m = file_positions(path, args.skeleton, args.start, args.end, args.source_fps)
        result = retarget(positions, names, fps, unit_m=unit_m, fps_out=args.fps, mapping=mapping, body=body,
                          where=args.source)
    frames = list(render_motion(body.model, result.qpos, width=args.size, height=args.size,
                                spheres=result.source_positions, sphere_radius=0.03))
    n = write_video(args.out, frames, result.fps)
    res = 100.0 * result.residual
    print(f"{args.out}: {n} frames at {result.fps:g} fps; residual mean {res.mean():.2f} cm, max {res.max():.2f} cm")
    chosen = list(np.linspace(0, n - 1, args.stills).round().astype(int)) if args.stills > 0 else []
    worst = np.argsort(-result.residual.max(axis=1), kind="stable")[:max(args.worst_stills, 0)]
    if len(chosen) or len(worst):
        import cv2

        out = Path(args.out)
        for i in sorted(set(chosen) | set(int(t) for t in worst)):
            still = out.with_name(f"{out.stem}_{i:04d}.png")
            write_atomic(still, lambda fh, i=i: fh.write(cv2.imencode(".png", cv2.cvtColor(frames[i], cv2.COLOR_RGB2BGR))[1]
                                                          .tobytes()))
            print(f"  still {still} (residual max {100.0 * result.residual[i].max():.1f} cm)")
    return 0


def _library_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("sources", nargs="+", help="capture set directories (each with its MANIFEST.csv)")
    p.add_argument("--out", default="captures", help="the library directory (default: captures); a set of the "
                                                     "same name is replaced once the new one is built and checked")


@command("build-library", _library_args)
def _build_library(args: argparse.Namespace) -> int:
    """Retarget capture sets into the repository's capture library and check it (docs/captures.md)."""
    from tqdm import tqdm

    from harness.io import check_output_dir
    from harness.motion.captures import MANIFEST_NAME, read_manifest
    from harness.motion.library import build_library, check_library

    check_output_dir(args.out)
    total = sum(len(read_manifest(Path(s) / MANIFEST_NAME)) for s in args.sources)
    with tqdm(total=total, unit="row", desc="retargeting", disable=None) as bar:
        quality = build_library(args.sources, args.out, progress=bar.update)
    for name, rows in quality.items():
        print(f"{name}: {len(rows)} rows, mean residual {np.median([q['mean_cm'] for q in rows]):.2f} cm median, "
              f"{max(q['mean_cm'] for q in rows):.2f} cm worst; worst maximum {max(q['max_cm'] for q in rows):.2f} cm")
    counts = check_library(args.out)
    size = sum(f.stat().st_size for f in Path(args.out).rglob("*") if f.is_file())
    print(f"{args.out}: {sum(counts.values())} rows in {len(counts)} sets ({', '.join(counts)}), "
          f"{size / 2**20:.1f} MB; checked")
    return 0


def _check_library_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("library", nargs="?", default="captures", help="the library directory (default: captures)")


@command("check-library", _check_library_args)
def _check_library(args: argparse.Namespace) -> int:
    """Check the capture library without its sources: every row loads, each set has its terms, size bound."""
    from harness.motion.library import check_library

    counts = check_library(args.library)
    print(f"{args.library}: " + ", ".join(f"{name} {n} rows" for name, n in counts.items()) + "; checked")
    return 0
