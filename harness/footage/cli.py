"""``harness track-video VIDEO --out DIR``: the people of a video followed, their flows, what the engine
recognises and recovers for each, and an annotated video (docs/video.md).

Nothing is written until everything has been computed: an unreadable video, no person found or a clip too short
is one line on stderr, exit status 2, and no ``DIR``.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
import time
from pathlib import Path

from harness.commands import command
from harness.footage.reader import VideoInputError

DEFAULT_MIN_SECONDS = 2.0    # s a person must be followed for the engine to run on them: a walking cycle at
                             # the slowest cadence is about 1.2 s, and recognition needs more than one


def _args(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", help="a video file OpenCV can read (AVI, MP4, ...)")
    p.add_argument("--out", required=True, help="directory to write people.csv, one observation .npz per person, "
                                              "their estimates and annotated.mp4 into")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--fov", type=float, default=None, help="the camera's horizontal field of view, degrees")
    cam.add_argument("--focal", type=float, default=None, help="the camera's focal length, pixels")
    p.add_argument("--elevation", type=float, default=None,
                   help="how far the camera looks down, degrees (the camera prior; default: unknown)")
    p.add_argument("--database", default=None, help="motion database (.npz) learned at the video's frame rate "
                                                    "(default: the procedural database, trained on the spot)")
    p.add_argument("--roi", default=None, help="x,y,w,h: follow only this region of the frame, as one person")
    p.add_argument("--min-seconds", type=float, default=DEFAULT_MIN_SECONDS,
                   help=f"run the engine on people followed at least this long (default {DEFAULT_MIN_SECONDS:g})")
    p.add_argument("--seed", type=int, default=0, help="the engine's seed")
    p.add_argument("--no-video", action="store_true", help="do not write annotated.mp4")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def parse_roi(text: str | None, width: int, height: int) -> tuple[int, int, int, int] | None:
    """``x,y,w,h`` in whole pixels, inside a ``width x height`` frame."""
    if text is None:
        return None
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise VideoInputError(f"--roi {text!r}: must be four whole numbers x,y,w,h (pixels)") from None
    if w < 16 or h < 16 or x < 0 or y < 0 or x + w > width or y + h > height:
        raise VideoInputError(f"--roi {text!r}: must lie inside the {width}x{height} frame and be at least 16 px "
                              f"a side")
    return x, y, w, h


def _check(args) -> None:
    """Every argument that can be checked before the video is opened."""
    import math

    from harness.io import check_output_dir

    check_output_dir(args.out)
    if Path(args.out).exists() and any(Path(args.out).iterdir()):
        raise VideoInputError(f"--out {args.out}: exists and is not empty (choose a new directory)")
    if not (math.isfinite(args.min_seconds) and 0.1 <= args.min_seconds <= 3600.0):
        raise VideoInputError(f"--min-seconds {args.min_seconds}: must be in [0.1, 3600]")
    if not 0 <= args.seed < 2**63:
        raise VideoInputError(f"--seed {args.seed}: must be in [0, 2**63)")


@command("track-video", _args)
def track_video(args: argparse.Namespace) -> int:
    """Follow the people of a video, recognise and recover each one's motion, write a table and an annotated video."""
    import numpy as np

    from harness.body import BodyModel
    from harness.engine import Tracker
    from harness.footage.foreground import LEARN_HISTORY
    from harness.footage.pipeline import follow_people
    from harness.footage.reader import probe, read_frames, sample_frames
    from harness.footage.recognise import (default_database, gravity, intrinsics, load_database,
                                           person_observation, summarise)

    _check(args)
    info = probe(args.video)
    roi = parse_roi(args.roi, info.width, info.height)
    intr, focal_source = intrinsics(info.width, info.height, args.fov, args.focal)
    if args.elevation is not None:
        gravity(args.elevation, 1)          # checked now, not after the work
    db = None if args.database is None else load_database(args.database, info.fps)
    if args.fov is None and args.focal is None:
        print(f"warning: no --fov or --focal: assuming {focal_source}; recovered distances scale with the focal "
              f"length", file=sys.stderr)

    bar = _progress(info.frames, "following", args.quiet)
    background = sample_frames(info, LEARN_HISTORY)
    result = follow_people(read_frames(info), info.fps, background, roi, progress=lambda t: bar.update(1))
    bar.close()
    duration = result.n_frames / info.fps
    if duration < args.min_seconds:
        raise VideoInputError(f"{args.video}: the clip lasts {duration:.1f} s ({result.n_frames} frames), shorter "
                              f"than --min-seconds {args.min_seconds:g}")
    if not result.people:
        raise VideoInputError(f"{args.video}: no person found (nothing moved in {result.n_frames} frames)")
    observations = {p.id: person_observation(p, info.fps, intr, args.elevation) for p in result.people}
    # The engine runs on people followed long enough on whom features were found at all.
    long_enough = [p for p in result.people
                   if p.n_frames / info.fps >= args.min_seconds and observations[p.id].counts.sum() > 0]
    if not long_enough:
        longest = max(p.n_frames for p in result.people) / info.fps
        raise VideoInputError(f"{args.video}: no person followed for --min-seconds {args.min_seconds:g} s with "
                              f"features on them (the longest followed: {longest:.1f} s)")

    trained = db is None
    if trained:
        db = default_database(info.fps)
    body = BodyModel.load()
    engine = Tracker(db, body)
    estimates, answers = {}, {}
    bar = _progress(len(long_enough), "engine", args.quiet, unit="person")
    for p in long_enough:
        t0 = time.perf_counter()
        est = engine.run(observations[p.id], rng=np.random.default_rng(args.seed))
        estimates[p.id], answers[p.id] = est, summarise(est, time.perf_counter() - t0)
        bar.update(1)
    bar.close()

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from harness.io import save_npz_atomic, write_text_atomic

    for p in result.people:
        observations[p.id].save(out / f"person_{p.id:03d}.npz")
        if p.id in estimates:
            est = estimates[p.id]
            save_npz_atomic(out / f"person_{p.id:03d}_estimate.npz", {
                "classes": est.classes.astype(str), "qpos": est.qpos, "class_posterior": est.class_posterior,
                "first_frame": np.array(p.first)})
    if trained:
        save_npz_atomic(out / "database.npz", db.to_arrays())
    write_text_atomic(out / "people.csv", people_table(result, answers))
    if not args.no_video:
        _write_video(out / "annotated.mp4", info, result, estimates, intr, body, args.quiet)
    following_fps = result.n_frames / max(result.seconds, 1e-9)
    engine_s = sum(a.seconds for a in answers.values())
    walk = sum(a.answer == "walk" for a in answers.values())
    print(f"{out}: {len(result.people)} people followed in {result.n_frames} frames ({info.width}x{info.height}, "
          f"{info.fps:g} fps; following {following_fps:.0f} frames/s), the engine ran on {len(answers)} followed "
          f"at least {args.min_seconds:g} s ({engine_s:.1f} s): {walk} answered walk; focal from {focal_source}")
    return 0


def people_table(result, answers: dict) -> str:
    """``people.csv``: one row per person followed, in order of appearance (no timings: the same video gives
    the same table)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["person", "first_frame", "last_frame", "frames", "seconds", "answer", "confidence", "top3",
                "mean_flows", "height_px", "speed_heights_per_s", "grouped_frames"])
    for p in sorted(result.people, key=lambda p: (p.first, p.id)):
        a = answers.get(p.id)
        counts = [len(f) for f in p.frame_flows()[1:]]
        w.writerow([p.id, p.first, p.last, p.n_frames, f"{p.n_frames / result.fps:.1f}",
                    a.answer if a else "", f"{a.confidence:.3f}" if a else "",
                    "; ".join(f"{c} {v:.2f}" for c, v in a.top) if a else "",
                    f"{(sum(counts) / len(counts)) if counts else 0.0:.1f}", f"{p.height_px():.0f}",
                    f"{p.speed(result.fps):.2f}", len(p.grouped)])
    return buf.getvalue()


def _write_video(path: Path, info, result, estimates: dict, intr, body, quiet: bool) -> None:
    import cv2

    from harness.body import body_origins
    from harness.footage.annotate import annotate_frame
    from harness.footage.reader import read_frames
    from harness.video import Mp4Writer

    joints = {i: body_origins(body, est.qpos) for i, est in estimates.items()}
    parents = body.model.body_parentid[1:] - 1
    bar = _progress(result.n_frames, "video", quiet)
    with Mp4Writer(path, info.fps) as writer:
        for t, frame in enumerate(read_frames(info)):
            if t >= result.n_frames:
                break
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
            writer.write(annotate_frame(rgb, t, result, estimates, joints, intr, parents))
            bar.update(1)
    bar.close()


def _progress(total: int, desc: str, quiet: bool, unit: str = "frame"):
    from tqdm import tqdm

    return tqdm(total=total or None, desc=desc, unit=unit, disable=quiet or not sys.stderr.isatty(), leave=False)
