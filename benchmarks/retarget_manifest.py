"""Retargeting quality and speed over a capture set: every manifest row of the sample CMU captures.

Run: ``python benchmarks/retarget_manifest.py [DIR] [--fps 30]`` (DIR defaults to ``../shared/mocap/cmu``).
Per row: source frames, solved frames, the mean and 95th-percentile joint-position residual after
retargeting (humanoid scale, cm; target: mean < 3 cm) and, for walking rows, the lowest foot point during
stance (cm above the floor, mean/min/max; target: mean within 3 cm; the floor is put at a low percentile of
these points, so the minimum is how deep the deepest stance frame sinks).
"""

import argparse
import time
from pathlib import Path

import numpy as np

from harness.body import BodyModel
from harness.motion.captures import MANIFEST_NAME, read_manifest, retarget_rows
from harness.motion.retarget import stance_foot_heights

DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "mocap" / "cmu"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR))
    parser.add_argument("--fps", type=float, default=30.0)
    args = parser.parse_args()
    directory = Path(args.directory)
    rows = read_manifest(directory / MANIFEST_NAME)
    body = BodyModel.load()
    t0 = time.perf_counter()
    results = retarget_rows(directory, rows, args.fps, body)
    elapsed = time.perf_counter() - t0
    print(f"{'row':>3} {'file':10} {'class':6} {'src':>5} {'ik':>4} {'mean cm':>8} {'p95 cm':>7} "
          f"{'max cm':>7} {'stance foot cm (mean/min/max)':>34}")
    means, n_src, n_ik = [], 0, 0
    for row, (motion, result) in zip(rows, results):
        res = 100.0 * result.residual
        means.append(res.mean())
        n_src += row.end - row.start
        n_ik += motion.n_frames
        stance = ""
        if row.label == "walk":
            h = 100.0 * stance_foot_heights(body, motion.qpos, motion.fps)
            stance = f"{h.mean():6.2f} / {h.min():6.2f} / {h.max():6.2f} ({len(h)} fr)"
        print(f"{row.line:>3} {row.file:10} {row.label:6} {row.end - row.start:>5} {motion.n_frames:>4} "
              f"{res.mean():8.2f} {np.percentile(res, 95):7.2f} {res.max():7.2f} {stance:>34}")
    print(f"{len(rows)} rows, {n_src} source frames, {n_ik} solved at {args.fps:g} fps in {elapsed:.1f} s "
          f"({1e3 * elapsed / n_ik:.1f} ms per solved frame); mean residual {np.mean(means):.2f} cm, "
          f"worst row {np.max(means):.2f} cm")


if __name__ == "__main__":
    main()
