"""Speed of track-video's image processing on one core (issue 62: following people and tracking their features at
least 30 frames per second at 768x576), beside a naive reference measured in the same run, and the engine's time
apart. Prints a table; exits 1 when the requirement is missed.

    taskset -c 0 env MUJOCO_GL=egl PYTHONPATH=. python benchmarks/video_speed.py [--video ../shared/video/vtest.avi]

Rows (OpenCV held to one thread; decoding the video is timed apart and left out of every row):
- following: the whole pipeline (``harness.footage.pipeline.follow_people``: the background learned from 100
  frames spread over the clip, then per frame MOG2, blobs, assignment, corners, Lucas-Kanade both ways);
- following one region: the same with ``--roi`` (only that region is processed);
- Farneback: OpenCV's dense optical flow (``calcOpticalFlowFarneback``, its documented example settings) on the
  same frames, the naive reference: flow everywhere, then find the people in it;
- engine: the engine on every person followed at least 2 s (default database at the video's frame rate), per
  person-frame.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REQUIRED_FPS = 30.0
DEFAULT_VIDEO = Path(__file__).resolve().parents[2] / "shared" / "video" / "vtest.avi"
ROI = (300, 150, 256, 256)       # x, y, w, h: the path's middle, where people cross in front of the lamp post


def main(argv=None) -> int:
    from harness.footage.foreground import LEARN_HISTORY
    from harness.footage.pipeline import follow_people
    from harness.footage.reader import probe, read_frames, sample_frames

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default=str(DEFAULT_VIDEO))
    ap.add_argument("--no-engine", action="store_true")
    args = ap.parse_args(argv)
    if not Path(args.video).is_file():
        print(f"skipped: footage not found at {args.video} (the ../shared checkout is absent)")
        return 0
    cv2.setNumThreads(1)
    info = probe(args.video)

    t0 = time.perf_counter()
    n = sum(1 for _ in read_frames(info))
    decode = time.perf_counter() - t0
    background = sample_frames(info, LEARN_HISTORY)
    rows = [("decoding (left out below)", n, decode)]
    whole = follow_people(read_frames(info), info.fps, background)
    rows.append(("following everyone", whole.n_frames, whole.seconds))
    region = follow_people(read_frames(info), info.fps, background, roi=ROI)
    rows.append((f"following one region {ROI[2]}x{ROI[3]}", region.n_frames, region.seconds))

    spent, prev = 0.0, None
    for frame in read_frames(info):
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        t0 = time.perf_counter()
        if prev is not None:
            cv2.calcOpticalFlowFarneback(prev, grey, None, 0.5, 3, 15, 3, 5, 1.2, 0)
        spent += time.perf_counter() - t0
        prev = grey
    rows.append(("Farneback dense flow (reference)", n, spent))

    print(f"{info.path}: {info.width}x{info.height}, {n} frames, {info.fps:g} fps; OpenCV threads: "
          f"{cv2.getNumThreads()}\n")
    print("| stage | frames | seconds | frames per second | against Farneback |")
    print("|---|---|---|---|---|")
    for name, frames, seconds in rows:
        print(f"| {name} | {frames} | {seconds:.2f} | {frames / seconds:.0f} | {spent / seconds * frames / n:.1f}x |")
    if not args.no_engine:
        from harness.body import BodyModel
        from harness.engine import Tracker
        from harness.footage.recognise import default_database, intrinsics, person_observation

        intr, _ = intrinsics(info.width, info.height)
        engine = Tracker(default_database(info.fps), BodyModel.load())
        people = [p for p in whole.people if p.n_frames >= 2 * info.fps]
        t0, frames = time.perf_counter(), 0
        for p in people:
            obs = person_observation(p, info.fps, intr, 20.0)
            if obs.counts.sum() == 0:
                continue
            engine.run(obs, rng=np.random.default_rng(0))
            frames += len(obs)
        seconds = time.perf_counter() - t0
        print(f"\nengine (apart): {len(people)} people followed >= 2 s, {frames} person-frames in {seconds:.1f} s: "
              f"{1e3 * seconds / max(frames, 1):.1f} ms per person-frame (the first run includes compiling)")
    fps = whole.n_frames / whole.seconds
    print(f"\nrequirement: following everyone >= {REQUIRED_FPS:g} frames/s on one core: "
          f"{'met' if fps >= REQUIRED_FPS else 'MISSED'} ({fps:.0f})")
    return 0 if fps >= REQUIRED_FPS else 1


if __name__ == "__main__":
    sys.exit(main())
