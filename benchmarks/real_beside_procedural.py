"""Contact sheets of a procedural demonstration above a real one of the same primitive (docs/performer.md).

Run: ``python benchmarks/real_beside_procedural.py [DIR] [--classes punch,throw,wave,kick] [--out docs/performer]``
(DIR defaults to ``../shared/mocap/cmu``). Per class: the calibrated performer's take of seed 0 (top row) and the
first report demonstration of the class (``realism.calibration_split``: a subject the calibration never saw;
bottom row, left-sided ones shown as they were performed), six evenly spaced frames each, front three-quarter
view; written to ``OUT/<class>_real.png``.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

from harness.body import BodyModel
from harness.motion.captures import load_capture_set
from harness.motion.performer import demonstrations
from harness.motion.realism import calibration_split
from harness.motion.render_cli import _write_png, contact_sheet
from harness.video import render_motion

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DIR = ROOT.parent / "shared" / "mocap" / "cmu"
FRAMES = 6
VIEW = dict(width=150, height=190, distance=3.3, azimuth=150.0, elevation=-12.0, follow=True)


def sheet(body: BodyModel, motion, caption: str) -> np.ndarray:
    picks = np.unique(np.linspace(0, motion.n_frames - 1, FRAMES).round().astype(int))
    images = list(render_motion(body.model, np.asarray(motion.qpos)[picks], **VIEW))
    return contact_sheet(images, caption, [t / motion.fps for t in picks])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR))
    parser.add_argument("--classes", default="punch,throw,wave,kick")
    parser.add_argument("--out", default=str(ROOT / "docs" / "performer"))
    args = parser.parse_args()
    body = BodyModel.load()
    _, report = calibration_split(load_capture_set(args.directory))
    for label in args.classes.split(","):
        real = next(m for m in report if m.label == label)
        procedural = demonstrations(label, 1, np.random.default_rng(0), body=body)[0]
        top = sheet(body, procedural, f"procedural {label}, s{procedural.subject}, seed 0")
        bottom = sheet(body, real, f"real {label}: CMU {real.demo}")
        width = max(top.shape[1], bottom.shape[1])
        pad = lambda im: np.pad(im, ((0, 0), (0, width - im.shape[1]), (0, 0)))  # noqa: E731
        path = Path(args.out) / f"{label}_real.png"
        _write_png(path, np.concatenate([pad(top), pad(bottom)], axis=0))
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
