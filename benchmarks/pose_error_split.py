"""What the camera-frame joint error is made of: the orientation or the position of the baselink.

    python benchmarks/pose_error_split.py results/default [more result directories ...]

``mpjpe_cam_mm`` subtracts each skeleton's root before comparing joints in the camera frame, so the baselink's
position (its depth) does not enter it, while its orientation does. Per result directory, method and condition
(the ``occluders.amount`` of each row of ``runs.csv``): the mean ``mpjpe_cam_mm`` and ``mpjpe_pose_mm`` (the
posture alone, in the base frame); the correlation over runs of ``mpjpe_cam_mm`` with the baselink's rotation
error and with its depth error; and the mean ``mpjpe_cam_mm`` of the runs whose mean heading error is within
``--near`` degrees against those beyond ``--far``. Reads the runs of a finished (or interrupted) evaluation;
runs nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

METHODS = ("full", "full_smoothed", "gt_base")


def split(runs: pd.DataFrame, near: float, far: float) -> pd.DataFrame:
    """One row per method and condition present in ``runs`` (the columns of ``runs.csv``)."""
    rows = []
    condition = "occluders.amount" if "occluders.amount" in runs else "condition"
    for (method, amount), f in runs[runs.method.isin(METHODS)].groupby(["method", condition], sort=True):
        close, off = f[f.heading_err_deg <= near], f[f.heading_err_deg > far]
        rows.append({"method": method, condition: amount, "runs": len(f),
                     "mpjpe_cam_mm": f.mpjpe_cam_mm.mean(), "mpjpe_pose_mm": f.mpjpe_pose_mm.mean(),
                     "corr_rotation": f.mpjpe_cam_mm.corr(f.base_rot_err_deg),
                     "corr_depth": f.mpjpe_cam_mm.corr(f.base_depth_err_m),
                     f"runs_within_{near:g}deg": len(close), f"cam_within_{near:g}deg": close.mpjpe_cam_mm.mean(),
                     f"runs_beyond_{far:g}deg": len(off), f"cam_beyond_{far:g}deg": off.mpjpe_cam_mm.mean()})
    return pd.DataFrame(rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path, help="result directories (each with runs.csv)")
    parser.add_argument("--near", type=float, default=20.0, help="heading error (deg) of the 'near' runs")
    parser.add_argument("--far", type=float, default=45.0, help="heading error (deg) of the 'far' runs")
    args = parser.parse_args()
    for directory in args.results:
        path = directory / "runs.csv"
        if not path.is_file():
            print(f"error: {path} does not exist (run an evaluation into {directory} first)", file=sys.stderr)
            return 2
        print(f"{directory}:")
        print(split(pd.read_csv(path), args.near, args.far).to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
