"""Why the engine handed the true baselink (``gt_base``) loses real captures: which class wins along the true
path, which body part's flows hand it the win, and how the base's own motion enters.

    MUJOCO_GL=egl python benchmarks/given_pose_losses.py [--scenario scenarios/sim2real.yaml] [--mocap-dir DIR]
        [--base database given given+features given-horizontal given-rotation] [--floor 0.2 0.4 ...] [--set KEY=VALUE ...] [--class kick ...]
        [--jobs 2]

Every run of the scenario is scored as ``gt_base`` scores it: at the true base pose of every frame, each flow
under each state (``Scorer.recognise(pose_given=True)``), one recursion per primitive; the answer is the primitive
with the most evidence (the all-primitive recursion's argmax: the primitives do not switch). ``--base`` says
where a flow's predicted velocity takes the base's own motion from:

- ``database`` (what ``gt_base`` does): each state's base velocity features, so a flow's velocity also says
  how fast the body travels;
- ``given``: the true base path's velocity (central differences of the camera-frame base pose), every state's
  base velocity set to zero with no variance: the flows then carry only the body's motion relative to its base;
- ``given+features``: as ``given``, and each state also scores the six base velocity features (base frame) once
  per frame in joint space, with the joint-space method's per-feature outlier share
  (``MotionDatabase.log_emissions``): the base's travel as class evidence counted once, not once per flow;
- ``given-horizontal``: only the base's travel along the floor given (its base-frame forward and sideways
  velocity, carried as the camera's motion), those two features of every state at zero with no variance; the
  vertical and angular velocities stay the database's (a jump is its base's vertical motion);
- ``given-rotation``: only the base's angular velocity given, the linear one the database's.

``--floor S ...``: also ``database`` with every state's base linear velocity variance raised to at least ``S^2``
(m/s; after training, without refitting), one variant per value. ``--set``: also ``database`` under each of these
engine settings (``TrackerConfig`` fields, one variant each).

On a scenario that tests captures, each variant's count is also split into the development demonstrations (the
performer's calibration demonstrations, ``realism.calibration_split``: what settings are chosen on) and the report
ones. For the lost runs of the first ``--base``, the gap (the winner minus the true primitive, along the true path) is
split by body part with ``loss_causes.evidence_by_flow`` (ground-truth marker ids: a diagnosis only). Last, per
class, how the base moves in the tested demonstrations beside the procedural performer's takes (24, seed 1), which
the procedural database learned from: the net horizontal travel (m/s over the clip), and the base-frame forward
velocity's 10-90% range and the vertical velocity's standard deviation over all frames (``motion_features``); and
for the one-handed arm primitives where the acting hand goes (``hand_reach``).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import os
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import numpy as np
from scipy.spatial.transform import Rotation

import loss_causes
from harness import geometry
from harness.engine.features import BASE_ANGULAR, BASE_LINEAR, N_FEATURES, motion_features
from harness.engine.model import EngineModel
from harness.engine.recognition import FEATURE_OUTLIER, Recognizer

BASES = ("database", "given", "given+features", "given-horizontal", "given-rotation")
BASE_FEATURES = np.r_[BASE_LINEAR, BASE_ANGULAR]


def base_motion(pos: np.ndarray, quat: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``(T, 3)`` linear and angular velocity of a camera-frame base path (m/s, rad/s, camera frame): central
    differences (one-sided at the ends); the angular one from ``R_{t+1} R_t^T``, averaged onto the frames."""
    v = np.gradient(pos, axis=0) * fps
    rot = geometry.to_matrix(quat)
    step = Rotation.from_matrix(np.einsum("tij,tkj->tik", rot[1:], rot[:-1])).as_rotvec() * fps
    w = np.vstack([step[:1], 0.5 * (step[1:] + step[:-1]), step[-1:]]) if len(step) else np.zeros_like(v)
    return v, w


def carried_base(obs, pos: np.ndarray, v: np.ndarray, w: np.ndarray):
    """The observation with the base's motion given as the camera's: a point ``X`` of a base moving at ``v``,
    ``w`` (camera frame) moves relative to the camera at ``v + w x (X - t)``, which ``to_image``'s
    ``-(v_c + w_c x X)`` gives with ``v_c = -(v - w x t)``, ``w_c = -w``. ``pos``, ``v``, ``w`` are relative to
    the camera already (a moving camera's own motion is inside them)."""
    motion = np.concatenate([-(v - np.cross(w, pos)), -w], axis=1)
    return dataclasses.replace(obs, camera_motion=motion)


def without_base_velocity(model, config, features=BASE_FEATURES):
    """The engine model of the same database (and model points) with every state's base velocity (or only
    ``features`` of it) at zero, with no variance."""
    db = copy.deepcopy(model.db)
    db.means_[..., features] = 0.0
    db.covars_[..., features] = 1e-12
    return EngineModel.build(db, model.body, config.model_points, config.model_seed)


def with_floor(model, config, speed: float):
    """The engine model with every state's base linear velocity variance at least ``speed**2``."""
    db = copy.deepcopy(model.db)
    db.covars_[..., BASE_LINEAR] = np.maximum(db.covars_[..., BASE_LINEAR], speed ** 2)
    return EngineModel.build(db, model.body, config.model_points, config.model_seed)


def in_base_frame(quat: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Camera-frame vectors ``(T, 3)`` in the base frame of camera-frame orientations ``quat`` ``(T, 4)``."""
    return np.einsum("tji,tj->ti", geometry.to_matrix(quat), vectors)


class WithExtra(Recognizer):
    """A recursion that adds ``extra`` ``(C, K)`` (set before each frame) to the flows' emissions."""

    extra: np.ndarray | None = None

    def update(self, log_b):
        return super().update(log_b if log_b is None or self.extra is None else log_b + self.extra)


def class_evidence(model, db, config, obs, pos, quat, base_features: np.ndarray | None) -> np.ndarray:
    """``(C,)`` each primitive's evidence along the given path, flows scored at the given pose; with
    ``base_features`` ``(T, 106)``, the base velocity features' joint-space emissions added per frame."""
    from harness.engine.frame import observation_frames
    from harness.engine.scoring import Scorer

    scorer = Scorer(model, config)
    C = model.n_classes
    recs = [WithExtra(model.db, config.start_spread, config.prune).restrict([c]) for c in range(C)]
    keep = np.zeros(N_FEATURES, dtype=bool)
    keep[BASE_FEATURES] = True
    log_base = None if base_features is None else db.log_emissions(base_features, FEATURE_OUTLIER, keep)
    total, started = np.zeros(C), False
    for frame in observation_frames(obs, config):
        t = frame.index
        if not (started or frame.has_flows):
            continue
        for rec in recs:
            rec.predict()
            # A recursion restricted to one primitive never evaluates the others' states: one table serves all.
            rec.extra = None if log_base is None else log_base[t]
        started = True
        total += scorer.recognise(frame, recs, np.repeat(pos[t][None], C, axis=0), np.repeat(quat[t][None], C, axis=0),
                                  pose_given=True)
    return total


def scored_as(base: str, zeroed, obs, pos, quat, v, w, features):
    """``(model, observation, base features or None)`` that ``class_evidence`` scores a run with for ``base``
    (module docstring): the base's motion given in part or whole is carried as the camera's, and the same part
    of every state's base velocity is zeroed (``zeroed(features)``: the engine model with those features of
    every state at zero, ``without_base_velocity``; ``zeroed(None)``: the model itself)."""
    if base == "database":
        return zeroed(None), obs, None
    if base == "given-horizontal":
        along_floor = features[:, BASE_LINEAR].copy()
        along_floor[:, 2] = 0.0
        v_floor = np.einsum("tij,tj->ti", geometry.to_matrix(quat), along_floor)     # back to the camera frame
        return (zeroed(tuple(np.r_[BASE_LINEAR][:2])), carried_base(obs, pos, v_floor, np.zeros_like(w)), None)
    if base == "given-rotation":
        return zeroed(tuple(np.r_[BASE_ANGULAR])), carried_base(obs, pos, np.zeros_like(v), w), None
    return (zeroed(tuple(BASE_FEATURES)), carried_base(obs, pos, v, w),
            features if base == "given+features" else None)


def _one(job) -> dict:
    run, bases, floors, settings = job
    from harness.engine.config import settings_from_strings
    from harness.evaluation import pipeline

    inputs = pipeline.run_inputs(run)
    tracker = inputs.tracker()
    model, config, truth, obs = tracker.model, tracker.config, inputs.truth, inputs.obs
    pos, quat = truth.base_pos_cam, truth.base_quat_cam
    classes = list(model.db.classes_)
    v, w = base_motion(pos, quat, obs.fps)
    features = np.zeros((len(pos), N_FEATURES))
    features[:, BASE_LINEAR] = in_base_frame(quat, v)
    features[:, BASE_ANGULAR] = in_base_frame(quat, w)
    row = {"key": run.key, "class": run.test_class, "answers": {}, "demo": (inputs.motion.demo, inputs.motion.label)}
    built = {}       # "given" and "given+features" zero the same features: one model for both

    def zeroed(feats):
        if feats is None:
            return model
        if feats not in built:
            built[feats] = without_base_velocity(model, config, list(feats))
        return built[feats]

    scored = {base: scored_as(base, zeroed, obs, pos, quat, v, w, features) for base in bases}
    for base, (m, o, extra) in scored.items():
        row["answers"][base] = classes[int(np.argmax(class_evidence(m, model.db, config, o, pos, quat, extra)))]
    for speed in floors:
        ev = class_evidence(with_floor(model, config, speed), model.db, config, obs, pos, quat, None)
        row["answers"][f"database, floor {speed:g} m/s"] = classes[int(np.argmax(ev))]
    for item in settings:
        changed = dataclasses.replace(config, **settings_from_strings([item]))
        ev = class_evidence(model, model.db, changed, obs, pos, quat, None)
        row["answers"][f"database, {item}"] = classes[int(np.argmax(ev))]
    first = row["answers"][bases[0]]
    if first != run.test_class:
        m, o, _ = scored[bases[0]]
        won = loss_causes.evidence_by_flow(m, config, o, pos, quat, classes.index(first), pose_given=True)
        true = loss_causes.evidence_by_flow(m, config, o, pos, quat, classes.index(run.test_class), pose_given=True)
        segment = np.array([loss_causes.part_of(inputs.body.model.body(int(b)).name) for b in truth.markers.body]
                           + ["outlier"])
        gap = dict.fromkeys(loss_causes.PARTS, 0.0)
        for a, b, ids in zip(won, true, truth.marker_ids):
            for part, d in zip(segment[np.asarray(ids, dtype=int)], a - b):
                gap[part] += float(d)
        row["by_part"] = gap
    row["travel"] = travel(inputs.motion)
    if row["class"] in ARM_CLASSES:
        row["hand"] = hand_reach(model.body, inputs.motion)
    row["base_velocity"] = motion_features(inputs.motion)[:, BASE_LINEAR].tolist()
    return row


# The one-handed arm primitives (``realism.ACTING``'s arm classes), whose acting hand ``hand_reach`` follows.
ARM_CLASSES = ("punch", "throw", "wave")


def hand_reach(body, motion) -> tuple[float, float, float, float]:
    """The acting hand of a one-handed primitive (``realism.acting_side``) against its shoulder (the humerus's
    origin), in the base frame (x forward, z up): at the frame of its farthest forward reach, how far forward and
    how high (m); the highest it gets over the clip; and its fastest speed against the shoulder (m/s, between
    frames). MuJoCo's forward kinematics of the retargeted angles."""
    import mujoco

    from harness.motion.realism import acting_side

    side = acting_side(motion) or "r"
    model = body.model
    data = mujoco.MjData(model)
    hand, shoulder = model.body(side + "hand").id, model.body(side + "humerus").id
    offsets = []
    for qpos in motion.qpos:
        data.qpos[:] = np.concatenate([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], qpos[7:]])
        mujoco.mj_kinematics(model, data)
        offsets.append(data.xpos[hand] - data.xpos[shoulder])
    offsets = np.array(offsets)
    far = int(offsets[:, 0].argmax())
    speed = np.linalg.norm(np.diff(offsets, axis=0), axis=1) * motion.fps
    return float(offsets[far, 0]), float(offsets[far, 2]), float(offsets[:, 2].max()), float(speed.max())


def travel(motion) -> float:
    """Net horizontal travel of a demonstration's base over its duration (m/s)."""
    xy = motion.qpos[:, :2]
    return float(np.linalg.norm(xy[-1] - xy[0]) / (len(xy) / motion.fps))


def main() -> None:
    from harness.evaluation.runner import plan
    from harness.evaluation.scenario import load_scenario, resolve_capture
    from harness.motion.captures import load_capture_set
    from harness.motion.realism import calibration_split, procedural_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="scenarios/sim2real.yaml")
    ap.add_argument("--mocap-dir", default=os.environ.get("HARNESS_MOCAP_DIR", "../shared/mocap/cmu"))
    ap.add_argument("--base", nargs="+", default=list(BASES), choices=BASES)
    ap.add_argument("--floor", type=float, nargs="*", default=[], help="base linear velocity floors (m/s)")
    ap.add_argument("--set", dest="settings", nargs="*", default=[], metavar="KEY=VALUE",
                    help="engine settings, one variant each")
    ap.add_argument("--class", dest="classes", nargs="*", default=None, help="only runs of these test classes")
    ap.add_argument("--cache", default="results/cache")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    os.environ["HARNESS_MOCAP_DIR"] = args.mocap_dir         # the workers resolve the capture set again
    scenario = resolve_capture(load_scenario(args.scenario), args.mocap_dir)
    runs = [r for r in plan(scenario, args.cache) if args.classes is None or r.test_class in args.classes]
    if not runs:
        raise SystemExit("no runs selected (check --class and the scenario's classes)")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
        rows = list(pool.map(_one, [(r, tuple(args.base), tuple(args.floor), tuple(args.settings))
                               for r in runs]))

    labels = list(dict.fromkeys(r["class"] for r in rows))
    development = None
    if scenario.test.split == "captures":
        # The performer's calibration demonstrations: what settings are chosen on (realism.calibration_split).
        development = {(m.demo, m.label) for m in calibration_split(load_capture_set(args.mocap_dir))[0]}
    for base in rows[0]["answers"]:
        right = [r for r in rows if r["answers"][base] == r["class"]]
        lost = Counter((r["class"], r["answers"][base]) for r in rows if r["answers"][base] != r["class"])
        print(f"base velocity from {base}: {len(right)} of {len(rows)} right; per class "
              + ", ".join(f"{c} {sum(r['class'] == c for r in right)}/{sum(r['class'] == c for r in rows)}"
                          for c in labels))
        if development is not None:
            dev = [r for r in rows if tuple(r["demo"]) in development]
            print(f"  development {sum(r in right for r in dev)} of {len(dev)}, report "
                  f"{sum(r in right for r in rows if r not in dev)} of {len(rows) - len(dev)}")
        print("  lost as: " + ", ".join(f"{t}->{a} {n}" for (t, a), n in lost.most_common()))
    split = [r for r in rows if "by_part" in r]
    if split:
        print(f"\nthe gap (winner minus the true primitive along the true path, base from {args.base[0]}) by body part, "
              "median per true class (tempered nats; positive: the part's flows favour the winner)")
        print(f"  {'class':>12s} {'runs':>4s} " + " ".join(f"{p:>10s}" for p in loss_causes.PARTS[:-1]))
        for c in labels:
            sub = [r for r in split if r["class"] == c]
            if sub:
                print(f"  {c:>12s} {len(sub):4d} " + " ".join(f"{np.median([r['by_part'][p] for r in sub]):10.1f}"
                                                            for p in loss_causes.PARTS[:-1]))
    print("\nthe base's motion, tested demonstrations / procedural takes: net horizontal travel (median, m/s), "
          "base-frame forward velocity 10-90% (m/s), vertical velocity standard deviation (m/s)")
    for c in labels:
        mine = [r for r in rows if r["class"] == c]
        proc = procedural_set(c, 24, 1)
        tested = np.concatenate([np.asarray(r["base_velocity"]) for r in mine])
        made = np.concatenate([motion_features(m)[:, BASE_LINEAR] for m in proc])
        lo, hi = np.percentile(tested[:, 0], [10, 90])
        plo, phi = np.percentile(made[:, 0], [10, 90])
        print(f"  {c:>12s} travel {np.median([r['travel'] for r in mine]):5.2f} / {np.median([travel(m) for m in proc]):5.2f}"
              f"   forward {lo:5.2f} to {hi:5.2f} / {plo:5.2f} to {phi:5.2f}"
              f"   vertical {tested[:, 2].std():4.2f} / {made[:, 2].std():4.2f}")
    arms = [c for c in labels if c in ARM_CLASSES]
    if arms:
        from harness.body.model import BodyModel

        body = BodyModel.load()
        print("\nthe acting hand against its shoulder, tested demonstrations / procedural takes (median, m): at its "
              "farthest forward reach how far forward and how high, the highest over the clip, and the fastest "
              "(m/s)")
        for c in arms:
            tested = np.array([r["hand"] for r in rows if r["class"] == c])
            made = np.array([hand_reach(body, m) for m in procedural_set(c, 24, 1)])
            t, m = np.median(tested, axis=0), np.median(made, axis=0)
            print(f"  {c:>12s} forward {t[0]:.2f} / {m[0]:.2f}   height there {t[1]:+.2f} / {m[1]:+.2f} "
                  f"(10-90% {np.percentile(tested[:, 1], 10):+.2f} to {np.percentile(tested[:, 1], 90):+.2f} / "
                  f"{np.percentile(made[:, 1], 10):+.2f} to {np.percentile(made[:, 1], 90):+.2f})   highest "
                  f"{t[2]:+.2f} / {m[2]:+.2f}   fastest {t[3]:.1f} / {m[3]:.1f}")
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
