"""Retargeting quality over capture sets: every manifest row, checked against issue 14's limits.

Run: ``python benchmarks/retarget_manifest.py [DIR ...] [--fps 30] [--csv FILE]`` (DIR defaults to
``../shared/mocap/cmu`` and ``../shared/mocap/bandai``). A BVH row of a skeleton the built-in tables do not
know names its joint mapping in its ``skeleton`` column (Bandai's ``mapping.yaml``). Per row: source and solved
frames, the mean, 95th percentile and maximum of the scale-normalised residual (the distance between each target
and the body point that follows it, humanoid scale, over every frame and target; cm), the worst frames (largest
residual first) and, for walking rows, the lowest foot point during stance (cm above the floor, mean/min/max).
Exits 1 when a row misses ``mean <= 3 cm, p95 <= 8 cm, max <= 15 cm``
(``harness.motion.captures.RESIDUAL_LIMITS``).
"""

import argparse
import sys
import time
from pathlib import Path

from harness.body import BodyModel
from harness.motion.captures import (MANIFEST_NAME, quality_table, read_manifest, retarget_rows,
                                     write_quality_csv)
from harness.motion.retarget import stance_foot_heights

SHARED = Path(__file__).resolve().parents[2] / "shared" / "mocap"
DEFAULT_DIRS = (SHARED / "cmu", SHARED / "bandai")


def check_set(directory: Path, fps: float, body: BodyModel) -> list[dict]:
    """Print one set's table and summary; returns its quality rows (with the set's name)."""
    rows = read_manifest(directory / MANIFEST_NAME)
    t0 = time.perf_counter()
    results = retarget_rows(directory, rows, fps, body)
    elapsed = time.perf_counter() - t0
    table = quality_table(rows, results)
    print(f"\n{directory.name} ({directory})")
    print(f"{'row':>3} {'file':34} {'class':12} {'src':>5} {'ik':>4} {'mean cm':>8} {'p95 cm':>7} {'max cm':>7} "
          f"{'ok':>3}  {'worst frames':24} {'stance foot cm (mean/min/max)':>30}")
    for entry, row, (motion, _) in zip(table, rows, results):
        stance = ""
        if row.label == "walk":
            h = 100.0 * stance_foot_heights(body, motion.qpos, motion.fps)
            stance = f"{h.mean():5.2f} / {h.min():5.2f} / {h.max():5.2f} ({len(h)} fr)"
        print(f"{entry['row']:>3} {entry['file'][:34]:34} {entry['class']:12} {row.end - row.start:>5} "
              f"{entry['frames']:>4} {entry['mean_cm']:8.2f} {entry['p95_cm']:7.2f} {entry['max_cm']:7.2f} "
              f"{'yes' if entry['within_limits'] else 'NO':>3}  {entry['worst_frames']:24} {stance:>30}")
    n_ik = sum(e["frames"] for e in table)
    print(f"{directory.name}: {len(rows)} rows, {sum(r.end - r.start for r in rows)} source frames, {n_ik} solved at "
          f"{fps:g} fps in {elapsed:.1f} s ({1e3 * elapsed / n_ik:.1f} ms per solved frame); worst row mean "
          f"{max(e['mean_cm'] for e in table):.2f} cm, p95 {max(e['p95_cm'] for e in table):.2f} cm, max "
          f"{max(e['max_cm'] for e in table):.2f} cm")
    return [{"set": directory.name, **e} for e in table]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directories", nargs="*", default=[str(d) for d in DEFAULT_DIRS])
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--csv", default=None, help="also write the per-row table of every set to this CSV file")
    args = parser.parse_args()
    body = BodyModel.load()
    table = []
    for directory in map(Path, args.directories):
        table += check_set(directory, args.fps, body)
    if args.csv:
        write_quality_csv(args.csv, table)
        print(f"wrote {args.csv}")
    misses = [f"{e['set']} row {e['row']}" for e in table if not e["within_limits"]]
    if misses:
        print(f"rows beyond the limits: {', '.join(misses)}")
        return 1
    print(f"every row of {len(table)} within the limits")
    return 0


if __name__ == "__main__":
    sys.exit(main())
