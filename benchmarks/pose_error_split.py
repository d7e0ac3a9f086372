"""What the camera-frame joint error is made of, read from finished (or interrupted) evaluations.

    python benchmarks/pose_error_split.py results/default [more result directories ...]

Prints ``tables.pose_error_split`` (``pose_error_split.csv`` of every evaluation since 2026-12-06) of each
directory's ``runs.csv``, so that the results of evaluations made before that table existed can be read too.
Runs nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from harness.evaluation.tables import pose_error_split


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path, help="result directories (each with runs.csv)")
    args = parser.parse_args()
    for directory in args.results:
        path = directory / "runs.csv"
        if not path.is_file():
            print(f"error: {path} does not exist (run an evaluation into {directory} first)", file=sys.stderr)
            return 2
        print(f"{directory}:")
        print(pose_error_split(pd.read_csv(path)).to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
