"""Throughput of forward kinematics + point Jacobians (issue: 200 points x 100 configurations).

Run: ``make bench`` or ``python benchmarks/kinematics.py``. Prints the median of several repeats.
"""

import time

import numpy as np

from harness.body import BodyModel, forward_points, forward_points_and_jacobians, sample_surface


def main(points: int = 200, configs: int = 100, repeats: int = 7) -> None:
    body = BodyModel.load()
    rng = np.random.default_rng(0)
    surface = sample_surface(body, points, rng)
    qpos = body.qpos(body.random_angles(rng, configs))
    for name, fn in [("FK only", forward_points), ("FK + Jacobian", forward_points_and_jacobians)]:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn(body, qpos, surface.body, surface.local)
            times.append(time.perf_counter() - t0)
        med = float(np.median(times))
        print(f"{name:14s} {points} points x {configs} configs: {1e3 * med:7.2f} ms "
              f"({configs / med:8.0f} configs/s, {points * configs / med / 1e6:5.2f} M points/s)")


if __name__ == "__main__":
    main()
