"""End-to-end engine measurement on held-out procedural demonstrations (issue 5's acceptance script).

    MUJOCO_GL=egl python benchmarks/engine_end_to_end.py [--seeds 5] [--preset none|low_wall --amount 0.4]

Trains the database from ``--train`` demos per class (training seed 1000, subjects 0..99), tests on
``--seeds`` demos per class drawn with the evaluation seed (subjects 100..199, never seen in training):
100 markers, 1 px noise, camera at 4 m, random azimuth, coarse initialisation. Prints per-class rows and the
summary; tuning is done on --eval-seed values other than the reported one.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from harness import geometry
from harness.body import BodyModel
from harness.engine import MotionDatabase, Tracker, TrackerConfig, motion_features, recognize_features
from harness.motion.performer import CYCLIC
from harness.evaluation.metrics import mpjpe_pose_mm
from harness.motion.performer import CLASSES, demonstrations
from harness.scene import CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneSpec
from harness.scene.simulate import simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--train", type=int, default=8)
    ap.add_argument("--states", type=int, default=20)
    ap.add_argument("--eval-seed", type=int, default=2026)
    ap.add_argument("--preset", default="none")
    ap.add_argument("--amount", type=float, default=0.0)
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--gt-base", action="store_true", help="give the tracker the true base pose")
    ap.add_argument("--set", nargs="*", default=[], help="engine settings key=value (TrackerConfig fields)")
    ap.add_argument("--classes", nargs="*", default=list(CLASSES))
    args = ap.parse_args()

    body = BodyModel.load()
    t0 = time.perf_counter()
    train_rng = np.random.default_rng(1000)
    train = [m for c in CLASSES for m in
             (demonstrations(c, 1, train_rng, subject=int(s))[0] for s in range(args.train))]
    db = MotionDatabase(n_states=args.states, cyclic=CYCLIC).fit(train)
    print(f"database: {len(train)} demos, {time.perf_counter() - t0:.1f} s")
    tracker = Tracker(db, body, TrackerConfig(particles=args.particles, **{k: (int(v) if v.isdigit() else float(v)) for k, v in (a.split('=') for a in args.set)}), rng=np.random.default_rng(args.eval_seed))

    rng = np.random.default_rng(args.eval_seed)
    rows = []
    for c in args.classes:
        for i in range(args.seeds):
            motion = demonstrations(c, 1, rng, subject=100 + int(rng.integers(100)))[0]
            spec = SceneSpec(MarkerSpec(100, int(rng.integers(1 << 30))),
                             CameraSpec(distance=4.0, azimuth=float(rng.uniform(0, 360))),
                             OccluderSpec(args.preset, args.amount, int(rng.integers(1 << 30))),
                             ObservationSpec(noise_px=1.0))
            obs, truth = simulate(motion, spec, rng, body)
            js = db.classes_[recognize_features(db, motion_features(motion))[-1].argmax()]
            t1 = time.perf_counter()
            est = tracker.run(obs, base_pose=(truth.base_pos_cam, truth.base_quat_cam) if args.gt_base else None)
            ms = 1e3 * (time.perf_counter() - t1) / len(obs)
            q_true = truth.qpos.copy()
            q_true[:, :3], q_true[:, 3:7] = truth.base_pos_cam, truth.base_quat_cam
            pos_err = np.linalg.norm(est.qpos[:, :3] - truth.base_pos_cam, axis=1)
            f_err = np.linalg.norm(est.filter_pos - truth.base_pos_cam, axis=1)
            fwd_est = geometry.rotate(est.qpos[:, 3:7], np.array([1.0, 0, 0]))
            fwd_true = geometry.rotate(truth.base_quat_cam, np.array([1.0, 0, 0]))
            # Heading: angle between the forward axes projected on the camera's x-z plane (its floor, roughly).
            h_est, h_true = np.arctan2(fwd_est[:, 0], fwd_est[:, 2]), np.arctan2(fwd_true[:, 0], fwd_true[:, 2])
            head = np.rad2deg(np.abs(np.angle(np.exp(1j * (h_est - h_true)))))
            row = dict(cls=c, pred=est.predicted, js=js, mpjpe=mpjpe_pose_mm(body, est.qpos, q_true), pos=pos_err.mean(),
                       fpos=f_err.mean(), head=head.mean(), ms=ms, occ=truth.obstacle_fraction.mean(),
                       flows=obs.counts[1:].mean())
            rows.append(row)
            print(f"{c:13s} pred {row['pred']:13s} js {js:13s} mpjpe {row['mpjpe']:6.1f} mm  base {row['pos']:.3f} m "
                  f"(filter {row['fpos']:.3f})  heading {row['head']:5.1f} deg  {ms:5.1f} ms/f  "
                  f"flows {row['flows']:.0f} obst {row['occ']:.2f} az {spec.camera.azimuth:.0f}", flush=True)
    acc = np.mean([r["cls"] == r["pred"] for r in rows])
    js_acc = np.mean([r["cls"] == r["js"] for r in rows])
    print(f"\nruns {len(rows)}: recognition {100 * acc:.1f}%  joint-space {100 * js_acc:.1f}%  "
          f"MPJPE {np.mean([r['mpjpe'] for r in rows]):.1f} mm  base {np.mean([r['pos'] for r in rows]):.3f} m  "
          f"heading {np.mean([r['head'] for r in rows]):.1f} deg  {np.mean([r['ms'] for r in rows]):.1f} ms/frame")


if __name__ == "__main__":
    main()
