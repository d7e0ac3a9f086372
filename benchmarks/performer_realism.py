"""How far the procedural performer's joint-angle distributions are from real captures, before and after its
calibration (``harness.motion.realism``, ``harness.motion.calibration``).

Run: ``python benchmarks/performer_realism.py [DIR] [--fit] [--before TABLE.json] [--takes 24]`` (DIR defaults to
``../shared/mocap/cmu``). Every manifest row is retargeted and split into calibration and report
demonstrations (``realism.calibration_split``). Per class: the mean over the joints the real demonstrations
measure of the per-joint 1-D Wasserstein distance (degrees) between the real frames and the frames of
``--takes`` procedural takes (generator seed 1, not the fit's seed 0), for the performer before (``--before``, a
calibration table; default the uncalibrated performer, ``calibration.NEUTRAL``) and after (the shipped table),
on the calibration demonstrations (fitted on: an in-sample figure) and on the report demonstrations (held out:
the figure to quote), then on the report demonstrations over all 50 joints (the distance before issue 24),
median durations and left-side shares. ``--fit`` first fits the calibration on the calibration demonstrations
and writes ``harness/motion/calibration.json`` (the table the performer ships with). The table of a commit:
``git show COMMIT:harness/motion/calibration.json > before.json``.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from harness.motion.calibration import (CALIBRATION_PATH, NEUTRAL, default_calibration, read_calibration,
                                        save_calibration)
from harness.motion.captures import load_capture_set
from harness.motion.performer import CLASSES
from harness.motion.realism import calibration_split, class_report, fit_calibration, procedural_set, trial

DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "mocap" / "cmu"
EVALUATION_SEED = 1


def _who(motions) -> str:
    subjects = sorted({m.subject for m in motions}, key=int)
    trials = sorted({trial(m) for m in motions})
    return f"s{','.join(subjects)} ({','.join(trials)}; {len(motions)})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR))
    parser.add_argument("--fit", action="store_true", help="fit the calibration and write " + str(CALIBRATION_PATH))
    parser.add_argument("--before", default=None, metavar="TABLE", help="calibration table of 'before' "
                        "(default: the uncalibrated performer)")
    parser.add_argument("--takes", type=int, default=24, help="procedural takes per class (default 24)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    captures = load_capture_set(args.directory)
    calibrate, report = calibration_split(captures)
    if args.fit:
        table = fit_calibration(calibrate, progress=lambda msg: print(f"  fit {msg}", flush=True))
        save_calibration(CALIBRATION_PATH, table, {
            "fitted_by": "benchmarks/performer_realism.py --fit",
            "captures": "CMU sample set (../shared/mocap/cmu), calibration demonstrations of realism.calibration_split",
            "demonstrations": sorted(m.demo for m in calibrate)})
        default_calibration.cache_clear()
        print(f"wrote {CALIBRATION_PATH}")
    before_table = read_calibration(args.before) if args.before else {}
    table = default_calibration()
    print(f"{'class':12} {'calibrated on':38} {'reported on':38} {'calib. set deg':>15} {'report set deg':>15} "
          f"{'all 50 joints':>14} {'duration s (real/before/after)':>31} {'left (real/after)':>18}  "
          f"farthest joints after (report set)")
    sums = np.zeros(6)
    for label in CLASSES:
        cal_real = [m for m in calibrate if m.label == label]
        rep_real = [m for m in report if m.label == label]
        before = procedural_set(label, args.takes, EVALUATION_SEED, before_table.get(label, NEUTRAL))
        after = procedural_set(label, args.takes, EVALUATION_SEED, table.get(label, NEUTRAL))
        cb, ca = class_report(cal_real, before), class_report(cal_real, after)
        rb, ra = class_report(rep_real, before), class_report(rep_real, after)
        row = [cb["distance_deg"], ca["distance_deg"], rb["distance_deg"], ra["distance_deg"],
               rb["distance_all_deg"], ra["distance_all_deg"]]
        sums += row
        left = "" if np.isnan(ra["left_real"]) else f"{ra['left_real']:.2f}/{ra['left_procedural']:.2f}"
        print(f"{label:12} {_who(cal_real):38} {_who(rep_real):38} {row[0]:6.1f} -> {row[1]:4.1f} "
              f"{row[2]:6.1f} -> {row[3]:4.1f} {row[4]:5.1f} -> {row[5]:4.1f} "
              f"{ra['duration_real_s']:9.2f} / {rb['duration_procedural_s']:4.2f} / {ra['duration_procedural_s']:4.2f} "
              f"{left:>18}  {ra['farthest']}")
    m = sums / len(CLASSES)
    print(f"{'mean':12} {'':38} {'':38} {m[0]:6.1f} -> {m[1]:4.1f} {m[2]:6.1f} -> {m[3]:4.1f} {m[4]:5.1f} -> {m[5]:4.1f}")
    print(f"{len(captures)} demonstrations ({len(calibrate)} calibration, {len(report)} report), {args.takes} "
          f"procedural takes per class; before: {args.before or 'uncalibrated'}; {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
