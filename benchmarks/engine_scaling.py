"""Engine cost against its sizes: time per frame as particles, visible flows, model points, classes and tracks
grow, with the fitted exponent of each (the slope of log time against log size).

    MUJOCO_GL=egl python benchmarks/engine_scaling.py [--frames 12] [--quick]

One size changes at a time; the others stay at the default (500 particles, 100 markers of which about 41 are
visible per frame, 120 model points, 10 primitives). The tracks are kept at a fixed number (no pruning, no
merging) so that a frame's cost is that of the sizes it was given: the default run keeps every primitive's
five spawned tracks; the "tracks" sweep runs without tracks per primitive and spawns 1, 2, 3 or 5 (the lead,
its turns and its twin). More classes than the ten primitives are copies of the database's HMMs under new
names (the cost depends on the arrays' sizes, not on what they hold). Time per frame is the mean over the frames
after the first with flows (which spawns the tracks, reported apart). The cost should grow at most
linearly in each size: an exponent near 1 or below (fixed costs pull it below 1).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from harness.body import BodyModel
from harness.engine import MotionDatabase, Tracker, TrackerConfig
from harness.motion.performer import CLASSES, CYCLIC, demonstrations
from harness.scene import CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneSpec
from harness.scene.simulate import simulate

# No pruning, no merging: the tracks spawned on the first frame live through the clip.
_KEEP_TRACKS = {"tracks.prune_nats": 1e12, "tracks.merge_m": 0.0, "tracks.merge_deg": 0.0}


def copies(db: MotionDatabase, n_classes: int) -> MotionDatabase:
    """A database of ``n_classes`` primitives: the first ones of ``db``, then copies of its HMMs renamed."""
    out = MotionDatabase(db.n_states, cyclic=db.cyclic, n_iter=db.n_iter, mirrored=db.mirrored)
    take = np.arange(n_classes) % len(db.classes_)
    out.classes_ = np.array([f"{db.classes_[c]}#{i // len(db.classes_)}" if i >= len(db.classes_)
                             else db.classes_[c] for i, c in enumerate(take)])
    for name in ("cyclic_", "means_", "covars_", "transmat_", "startprob_"):
        setattr(out, name, getattr(db, name)[take].copy())
    out.fps_ = db.fps_
    return out.validate()


def frame_times(db: MotionDatabase, body: BodyModel, obs, config: TrackerConfig) -> tuple[float, float, int]:
    """Milliseconds of the first frame with flows (it spawns the tracks), the mean over the later frames, and
    the number of tracks kept."""
    tracker = Tracker(db, body, config, rng=np.random.default_rng(1))
    tracker.run(obs)                                        # compiles and warms the caches
    tracker.reset(obs.intrinsics, obs.fps, np.random.default_rng(1))
    times = []
    for flows in obs.flows:
        t0 = time.perf_counter()
        tracker.step(flows)
        if tracker.tracks:
            times.append(time.perf_counter() - t0)
    return 1e3 * times[0], 1e3 * float(np.mean(times[1:])), len(tracker.tracks)


def exponent(sizes: list[float], ms: list[float]) -> float:
    """The least-squares slope of log time against log size."""
    return float(np.polyfit(np.log(sizes), np.log(ms), 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12, help="frames per clip (default 12)")
    ap.add_argument("--quick", action="store_true", help="three sizes per sweep instead of four")
    args = ap.parse_args()
    body = BodyModel.load()
    rng = np.random.default_rng(0)
    train = [demonstrations(c, 1, rng, subject=s)[0] for c in CLASSES for s in range(3)]
    db = MotionDatabase(n_states=20, cyclic=CYCLIC).fit(train)
    motion = demonstrations("walk", 1, rng, subject=500)[0]
    motion = replace(motion, qpos=motion.qpos[:args.frames])

    def clip(markers: int):
        spec = SceneSpec(MarkerSpec(markers, 1), CameraSpec(azimuth=40.0), OccluderSpec(),
                         ObservationSpec(noise_px=1.0))
        return simulate(motion, spec, np.random.default_rng(7), body)[0]

    base = TrackerConfig.from_dict(_KEEP_TRACKS)
    default_clip = clip(100)
    sweeps = {
        "particles": [
            (n, db, default_clip, base.with_values({"tracks": {"particles": n}})) for n in (100, 200, 400, 800)
        ],
        "visible flows": [(m, db, clip(m), base) for m in (50, 100, 200, 400)],
        "model points": [(p, db, default_clip, base.with_values({"model": {"points": p}})) for p in (75, 150, 300)],
        "classes": [(c, copies(db, c), default_clip, base) for c in (5, 10, 20, 40)],
        "tracks": [
            (k, db, default_clip, base.with_values({"spawn": {"per_class": False, "turns": turns, "twin": twin}}))
            for k, turns, twin in (
                (1, (), False),
                (2, (), True),
                (3, (90.0, -90.0), False),
                (5, (90.0, 180.0, -90.0), True),
            )
        ],
    }
    print(f"{'sweep':14s} {'size':>6s} {'frame 1 ms':>11s} {'ms/frame':>9s} {'tracks':>7s}")
    summary = {}
    for name, runs in sweeps.items():
        if args.quick:
            runs = runs[:3]
        sizes, ms = [], []
        for size, database, obs, config in runs:
            first, later, n_tracks = frame_times(database, body, obs, config)
            shown = float(obs.counts[1:].mean()) if name == "visible flows" else size
            sizes.append(shown)
            ms.append(later)
            print(f"{name:14s} {shown:6.0f} {first:11.1f} {later:9.1f} {n_tracks:7d}", flush=True)
        summary[name] = exponent(sizes, ms)
    print("\nfitted exponent of time per frame (1: linear):")
    for name, e in summary.items():
        print(f"  {name:14s} {e:5.2f}")


if __name__ == "__main__":
    main()
