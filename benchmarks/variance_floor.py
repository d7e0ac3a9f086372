"""The database's human variance floor (``harness.engine.variance_floor``), measured on development captures.

Run: ``python benchmarks/variance_floor.py [DIR] [--fit]`` (DIR defaults to ``../shared/mocap/cmu``). The
development demonstrations are the performer's calibration demonstrations (``realism.calibration_split``: the
report subjects are never used). Per class, each take is held out in turn from a one-class database of the
class's other takes (a class with one take: each demonstration), and the held-out demonstrations' residual
variances about the state means are pooled per feature (median, left and right averaged). Prints the pooled
standard deviations per feature group beside the group floor; ``--fit`` writes
``harness/engine/human_floor.json``.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from harness.body.model import JOINT_NAMES
from harness.engine import MotionDatabase
from harness.engine.database import DEFAULT_STATES
from harness.engine.variance_floor import (FLOOR_SCALE, HUMAN_FLOOR_PATH, group_floor, held_out_residuals,
                                           pooled_floor, save_human_floor)
from harness.motion.captures import load_capture_set
from harness.motion.performer import CYCLIC
from harness.motion.realism import calibration_split, trial

DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "mocap" / "cmu"


def held_out_group(motions):
    """What is held out together: the take, for a class with several takes; else the demonstration."""
    takes = {}
    for m in motions:
        takes.setdefault(m.label, set()).add(trial(m))
    return lambda m: trial(m) if len(takes[m.label]) > 1 else m.demo


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR))
    parser.add_argument("--fit", action="store_true", help="write " + str(HUMAN_FLOOR_PATH))
    args = parser.parse_args()
    t0 = time.perf_counter()
    development, _ = calibration_split(load_capture_set(args.directory))
    fit = lambda ms: MotionDatabase(n_states=DEFAULT_STATES, cyclic=CYCLIC, floor=group_floor()).fit(ms)  # noqa: E731
    residuals = held_out_residuals(development, held_out_group(development), fit)
    table = pooled_floor([r for _, r in residuals])
    if args.fit:
        save_human_floor(HUMAN_FLOOR_PATH, table, {
            "fitted_by": "benchmarks/variance_floor.py --fit",
            "held_out": "leave-one-take-out (one take: leave-one-demonstration-out) per class",
            "demonstrations": sorted(m.demo for m in development), "held_out_demonstrations": len(residuals)})
        print(f"wrote {HUMAN_FLOOR_PATH}")
    names = list(JOINT_NAMES) + [f"d{n}" for n in JOINT_NAMES] + ["vx", "vy", "vz", "wx", "wy", "wz"]
    group = np.sqrt(group_floor())
    print(f"{'feature':16} {'group floor':>12} {'held-out std':>13} {'floor std (x' + str(FLOOR_SCALE) + ')':>17}")
    for i, name in enumerate(names):
        print(f"{name:16} {group[i]:12.3f} {np.sqrt(table[i]):13.3f} "
              f"{np.sqrt(max(group[i] ** 2, FLOOR_SCALE * table[i])):17.3f}")
    print(f"{len(residuals)} held-out demonstrations of {len(development)} development demonstrations "
          f"({', '.join(sorted({lbl for lbl, _ in residuals}))}); {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
