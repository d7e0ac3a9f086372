"""Commands for captured motion: ``import-capture`` (a capture set to Motion files) and ``capture-video``
(a retargeted capture beside its source skeleton, to check the retargeting by eye)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.commands import command
from harness.errors import HarnessError


def _import_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("directory", help="directory holding the capture files and (by default) MANIFEST.csv")
    p.add_argument("--manifest", default=None, help="manifest CSV (default: DIRECTORY/MANIFEST.csv)")
    p.add_argument("--out", default="captures", help="output directory for the Motion .npz files")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the retargeted motions")
    p.add_argument("--mapping", default=None, help="joint mapping file (YAML or CSV: source joint -> body)")
    p.add_argument("--classes", default=None, help="comma-separated allowed classes (others are an error)")


@command("import-capture", _import_args)
def _import_capture(args: argparse.Namespace) -> int:
    """Retarget every row of a capture set to humanoid56 and write one Motion .npz per row."""
    from harness.body import BodyModel
    from harness.motion.captures import MANIFEST_NAME, read_manifest, retarget_rows
    from harness.motion.skeletons import load_mapping

    body = BodyModel.load()
    directory = Path(args.directory)
    classes = [c.strip() for c in args.classes.split(",")] if args.classes else None
    rows = read_manifest(Path(args.manifest) if args.manifest else directory / MANIFEST_NAME, classes)
    mapping = load_mapping(args.mapping, body.body_names) if args.mapping else None
    out = Path(args.out)
    print(f"{'row':>4} {'file':14} {'class':8} {'frames':>6} {'mean cm':>8} {'max cm':>7}  output")
    for row, (motion, result) in zip(rows, retarget_rows(directory, rows, args.fps, body, mapping)):
        name = f"{row.line:03d}_{Path(row.file).stem}_{row.start}-{row.end}_{row.label}.npz"
        motion.save(out / name)
        res = 100.0 * result.residual
        print(f"{row.line:>4} {row.file:14} {row.label:8} {motion.n_frames:>6} {res.mean():8.2f} {res.max():7.2f}  "
              f"{out / name}")
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
    p.add_argument("--stills", type=int, default=0, help="also write this many evenly spaced PNG stills")
    p.add_argument("--size", type=int, default=480, help="frame width and height in pixels")


def _file_source(args: argparse.Namespace):
    from harness.motion.asf_amc import asf_forward_kinematics, joint_names, load_amc, load_asf
    from harness.motion.bvh import CMU_BVH_UNIT_M, load_bvh

    path = Path(args.source)
    if path.suffix.lower() == ".bvh":
        clip = load_bvh(path)
        return clip.positions(args.start, args.end), clip.names, clip.fps, CMU_BVH_UNIT_M
    if path.suffix.lower() == ".amc":
        if not args.skeleton:
            raise HarnessError(f"{path}: an .amc source needs --skeleton FILE.asf")
        skeleton = load_asf(args.skeleton)
        amc = load_amc(path, skeleton)
        return (asf_forward_kinematics(skeleton, amc, args.start, args.end), joint_names(skeleton),
                args.source_fps, skeleton.unit_m)
    raise HarnessError(f"{path}: capture-video takes a .bvh or .amc file or a manifest row number")


@command("capture-video", _video_args)
def _capture_video(args: argparse.Namespace) -> int:
    """Render a retargeted capture with the source skeleton's scaled joints drawn as spheres."""
    from harness.body import BodyModel
    from harness.motion.captures import MANIFEST_NAME, read_manifest, retarget_rows
    from harness.motion.retarget import retarget
    from harness.video import render_motion, write_video

    body = BodyModel.load()
    if args.source.isdigit():
        directory = Path(args.dir)
        rows = read_manifest(Path(args.manifest) if args.manifest else directory / MANIFEST_NAME)
        chosen = [r for r in rows if r.line == int(args.source)]
        if not chosen:
            raise HarnessError(f"manifest has no row {args.source} (rows: {rows[0].line}-{rows[-1].line})")
        (_, result), = retarget_rows(directory, chosen, args.fps, body)
    else:
        positions, names, fps, unit_m = _file_source(args)
        result = retarget(positions, names, fps, unit_m=unit_m, fps_out=args.fps, body=body, where=args.source)
    frames = list(render_motion(body.model, result.qpos, width=args.size, height=args.size,
                                spheres=result.source_positions, sphere_radius=0.03))
    n = write_video(args.out, frames, result.fps)
    res = 100.0 * result.residual
    print(f"{args.out}: {n} frames at {result.fps:g} fps; residual mean {res.mean():.2f} cm, max {res.max():.2f} cm")
    if args.stills > 0:
        import cv2

        out = Path(args.out)
        for i in np.linspace(0, n - 1, args.stills).round().astype(int):
            still = out.with_name(f"{out.stem}_{i:04d}.png")
            cv2.imwrite(str(still), cv2.cvtColor(frames[i], cv2.COLOR_RGB2BGR))
            print(f"  still {still}")
    return 0
