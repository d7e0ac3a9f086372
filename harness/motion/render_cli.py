"""``harness render-motion``: look at a procedural demonstration or a saved Motion.

Renders offscreen (``harness.video.render_motion``) to an MP4 or GIF (``--out``), optionally writes a few
PNG stills (``--stills DIR``) and a contact sheet: evenly spaced frames side by side in one small PNG
(``--sheet FILE``), which is how the images in ``docs/performer/`` were made.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.commands import command
from harness.errors import HarnessError
from harness.io import write_atomic


class RenderMotionError(HarnessError):
    """Bad arguments to ``render-motion``."""


def _args(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--class", dest="label", help="a procedural primitive (walk, run, kick, ...)")
    src.add_argument("--motion", type=Path, help="a saved Motion .npz file")
    p.add_argument("--seed", type=int, default=0, help="seed of the procedural demonstration (default 0)")
    p.add_argument("--subject", type=int, default=None, help="performer style id (default: drawn from the seed)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the procedural demonstration")
    p.add_argument("--out", type=Path, default=None, help="video file to write (.mp4 or .gif)")
    p.add_argument("--stills", type=Path, default=None, help="directory for a few PNG frames")
    p.add_argument("--n-stills", type=int, default=4, help="number of stills (default 4)")
    p.add_argument("--sheet", type=Path, default=None, help="contact-sheet PNG: evenly spaced frames side by side")
    p.add_argument("--sheet-frames", type=int, default=6, help="frames on the contact sheet (default 6)")
    p.add_argument("--width", type=int, default=320, help="frame width in pixels")
    p.add_argument("--height", type=int, default=320, help="frame height in pixels")
    p.add_argument("--azimuth", type=float, default=150.0, help="camera azimuth, degrees (MuJoCo free camera)")
    p.add_argument("--elevation", type=float, default=-12.0, help="camera elevation, degrees")
    p.add_argument("--distance", type=float, default=4.0, help="camera distance from the pelvis, metres")
    p.add_argument("--fixed", action="store_true", help="fixed camera at the start instead of following")
    p.add_argument("--save-motion", type=Path, default=None, help="also save the procedural Motion (.npz)")


def _check(args: argparse.Namespace) -> None:
    if args.out is None and args.stills is None and args.sheet is None and args.save_motion is None:
        raise RenderMotionError("nothing to write: give --out, --stills, --sheet or --save-motion")
    for name in ("width", "height", "n_stills", "sheet_frames"):
        if getattr(args, name) < 1:
            raise RenderMotionError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    if args.width > 1920 or args.height > 1920:
        raise RenderMotionError(f"frame size {args.width}x{args.height} is larger than 1920x1920")
    if not args.distance > 0:
        raise RenderMotionError(f"--distance must be positive, got {args.distance}")
    if args.out is not None and args.out.suffix.lower() not in (".mp4", ".gif"):
        raise RenderMotionError(f"--out {args.out}: video files must end in .mp4 or .gif")
    if args.sheet is not None and args.sheet.suffix.lower() != ".png":
        raise RenderMotionError(f"--sheet {args.sheet}: must end in .png")
    from harness.io import check_output_dir, check_output_file

    for flag in ("out", "sheet", "save_motion"):
        if getattr(args, flag) is not None:
            check_output_file(getattr(args, flag), f"--{flag.replace('_', '-')}")
    if args.stills is not None:
        check_output_dir(args.stills, "--stills")


def _write_png(path: Path, image: np.ndarray) -> None:
    import cv2

    ok, buf = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise RenderMotionError(f"{path}: cannot encode the image as PNG")
    write_atomic(path, lambda fh: fh.write(buf.tobytes()))


def contact_sheet(frames: list[np.ndarray], caption: str, times: list[float]) -> np.ndarray:
    """Frames ``(H, W, 3) uint8`` side by side with a caption on the first and the time on each."""
    import cv2

    tiles = []
    for f, t in zip(frames, times):
        tile = np.ascontiguousarray(f).copy()
        cv2.putText(tile, f"{t:.2f}s", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    sheet = np.concatenate(tiles, axis=1)
    cv2.putText(sheet, caption, (4, sheet.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                cv2.LINE_AA)
    return sheet


@command("render-motion", _args)
def render_motion_command(args: argparse.Namespace) -> int:
    """Render a procedural demonstration or a saved Motion offscreen to video, stills or a contact sheet."""
    from harness.body import BodyModel
    from harness.motion.motion import Motion
    from harness.motion.performer import demonstrations
    from harness.video import render_motion, write_video

    _check(args)
    body = BodyModel.load()
    if args.motion is not None:
        motion = Motion.load(args.motion)
        caption = f"{motion.label} ({args.motion.name})"
    else:
        motion = demonstrations(args.label, 1, np.random.default_rng(args.seed), fps=args.fps,
                                subject=args.subject, body=body)[0]
        caption = f"{motion.label} s{motion.subject} seed {args.seed}"
        if args.save_motion is not None:
            motion.save(args.save_motion)
            print(f"wrote {args.save_motion}")
    qpos = np.asarray(motion.qpos)
    want = set()
    stills = np.unique(np.linspace(0, len(qpos) - 1, args.n_stills).round().astype(int))
    sheet = np.unique(np.linspace(0, len(qpos) - 1, args.sheet_frames).round().astype(int))
    if args.stills is not None:
        want.update(stills.tolist())
    if args.sheet is not None:
        want.update(sheet.tolist())
    render_args = dict(width=args.width, height=args.height, distance=args.distance, azimuth=args.azimuth,
                       elevation=args.elevation, follow=not args.fixed)
    frames: dict[int, np.ndarray] = {}
    video = []
    if args.out is not None:                               # every frame for the video, keep the wanted ones
        for t, image in enumerate(render_motion(body.model, qpos, **render_args)):
            video.append(image)
            if t in want:
                frames[t] = image
    elif want:                                             # only the wanted frames
        order = sorted(want)
        start = qpos[0] if args.fixed else None
        sub = qpos[order] if start is None else np.concatenate([qpos[:1], qpos[order]])
        images = list(render_motion(body.model, sub, **render_args))
        frames = dict(zip(order, images[1:] if start is not None else images))
    if args.out is not None:
        n = write_video(args.out, video, motion.fps)
        print(f"wrote {args.out} ({n} frames, {motion.duration:.2f} s)")
    if args.stills is not None:
        args.stills.mkdir(parents=True, exist_ok=True)
        for t in stills:
            path = args.stills / f"{motion.label}_{t:04d}.png"
            _write_png(path, frames[int(t)])
        print(f"wrote {len(stills)} stills to {args.stills}")
    if args.sheet is not None:
        image = contact_sheet([frames[int(t)] for t in sheet], caption, [t / motion.fps for t in sheet])
        _write_png(args.sheet, image)
        print(f"wrote {args.sheet} ({image.shape[1]}x{image.shape[0]})")
    return 0
