"""Engine speed: ms per frame and its breakdown for 10 primitives, 200 particles, 100 markers, 150 points.

    MUJOCO_GL=egl python benchmarks/engine_speed.py [--classes walk kick ...]

Single process; numba's kernel is compiled (and cached) before timing. The target is 30 frames per second
(33 ms per frame) on one core.
"""

import argparse
import time

import numpy as np

from harness.body import BodyModel
from harness.engine import MotionDatabase, Tracker, TrackerConfig
from harness.engine.database import CYCLIC_PRIMITIVES
from harness.motion.performer import CLASSES, demonstrations
from harness.scene import CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneSpec
from harness.scene.simulate import simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--classes", nargs="*", default=["walk", "kick", "jumping_jack"])
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--points", type=int, default=150)
    args = ap.parse_args()
    body = BodyModel.load()
    rng = np.random.default_rng(0)
    train = [demonstrations(c, 1, rng, subject=s)[0] for c in CLASSES for s in range(6)]
    db = MotionDatabase(n_states=20, cyclic=CYCLIC_PRIMITIVES).fit(train)
    t0 = time.perf_counter()
    tracker = Tracker(db, body, TrackerConfig(particles=args.particles, model_points=args.points),
                      rng=np.random.default_rng(1))
    print(f"database transform (once): {1e3 * (time.perf_counter() - t0):.0f} ms for "
          f"{db.means_.shape[0] * db.means_.shape[1]} states x {args.points} points")
    spec = SceneSpec(MarkerSpec(100, 1), CameraSpec(azimuth=40.0), OccluderSpec(), ObservationSpec(noise_px=1.0))
    m = demonstrations("walk", 1, rng, subject=500)[0]
    tracker.run(simulate(m, spec, rng, body)[0])          # warm-up: numba compilation
    total, frames, parts = 0.0, 0, {}
    for c in args.classes:
        m = demonstrations(c, 1, rng, subject=501)[0]
        obs = simulate(m, spec, rng, body)[0]
        t1 = time.perf_counter()
        est = tracker.run(obs)
        total += time.perf_counter() - t1
        frames += len(obs)
        for k, v in est.timing.items():
            parts[k] = parts.get(k, 0.0) + v * len(obs)
        print(f"{c:13s} {len(obs)} frames, {obs.counts[1:].mean():.0f} flows/frame: "
              f"{1e3 * (time.perf_counter() - t1) / len(obs):.1f} ms/frame")
    ms = 1e3 * total / frames
    print(f"\nmean {ms:.1f} ms/frame ({1e3 / ms:.0f} fps); breakdown: "
          + ", ".join(f"{k} {v / frames:.1f} ms" for k, v in parts.items()))


if __name__ == "__main__":
    main()
