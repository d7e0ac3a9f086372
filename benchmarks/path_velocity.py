"""How well does a tracked path carry the base's velocity? The reported paths' base velocity against the truth's,
beside the database's base velocity spread: could a track's own path velocity be scored under its class?

    MUJOCO_GL=egl python benchmarks/path_velocity.py [--scenario scenarios/default.yaml] [--seed S]
        [--amount 0.0 0.4] [--limit N] [--jobs 2] [--set KEY=VALUE ...]

For every selected run the engine tracks the clip (both passes). From the causal estimate's base path (the
leader's pose at each frame) and the offline one (``full_smoothed``'s), the base-frame linear velocity by central
differences (``given_pose_losses.base_motion``), and the truth's; per run the RMS of their difference and of the
true velocity (m/s), and the database's base linear velocity standard deviation for the true class (median over
its states and the three axes). A track's path could be scored under a class's base velocity features only if its
velocity error is small beside that spread. ``--seed`` replaces the scenario's seed (development seeds).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import dev_runs
from given_pose_losses import base_motion, in_base_frame
from harness.engine.features import BASE_LINEAR


def base_frame_velocity(qpos: np.ndarray, fps: float) -> np.ndarray:
    """``(T, 3)`` the base-frame linear velocity of a camera-frame base path (``qpos[:, :7]``)."""
    return in_base_frame(qpos[:, 3:7], base_motion(qpos[:, :3], qpos[:, 3:7], fps)[0])


def _one(job) -> dict:
    run, overrides = job
    from harness.evaluation import pipeline

    inputs = pipeline.run_inputs(run)
    tracker = dev_runs.tracker_for(inputs, overrides)
    est = tracker.run(inputs.obs)
    truth, fps = inputs.truth, inputs.obs.fps
    true = base_frame_velocity(np.column_stack([truth.base_pos_cam, truth.base_quat_cam]), fps)
    db = tracker.model.db
    c = list(db.classes_).index(run.test_class)
    row = {"condition": run.condition_label, "true": float(np.sqrt(np.mean(true ** 2))),
           "spread": float(np.median(np.sqrt(db.covars_[c][:, BASE_LINEAR])))}
    for name, e in (("causal", est), ("offline", est.offline)):
        seen = np.isfinite(e.qpos[:, :7]).all(axis=1)
        row[name] = float(np.sqrt(np.mean((base_frame_velocity(e.qpos, fps) - true)[seen] ** 2)))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    args = ap.parse_args()
    runs = dev_runs.selected(args, pick=np.random.default_rng(0))
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(_one, runs, args)
    print("median over runs (m/s): base velocity error RMS of the causal and offline paths, the true velocity's RMS,"
          " the database's spread for the true class")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        med = {k: np.median([r[k] for r in sub]) for k in ("causal", "offline", "true", "spread")}
        print(f"  {cond} ({len(sub)} runs): causal {med['causal']:.2f}, offline {med['offline']:.2f}, "
              f"true {med['true']:.2f}, spread {med['spread']:.2f}")
    print(f"\n{len(runs)} runs in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
