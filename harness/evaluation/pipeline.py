"""One evaluation run: train (or load) the database, play the test motion in the scene, run every method,
score it against the ground truth. ``run_one(RunSpec) -> list[dict]``, one row per method.

Methods (``methods`` in a scenario):
- ``full``: the engine from flows alone (particle filter, recognition, recovery);
- ``gt_base``: the engine given the true baselink pose (isolates recognition and recovery from tracking);
- ``no_database``: per-frame fitting of the angles to the 2D points at the true baselink pose, without the
  HMM prior (what the database's prior adds, compared with ``gt_base``); no recognition;
- ``joint_space``: forward recognition from the true joint-space features (the upper bound); no recovery.

Random streams per run (all from the run's seed): the test motion, the scene (markers, azimuth, noise), and
the engine's particle filter, so that adding a method never changes another method's numbers.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from harness.body import BodyModel
from harness.engine import MotionDatabase, Tracker, TrackerConfig, motion_features, recognize_features
from harness.engine.database import CYCLIC_PRIMITIVES
from harness.engine.recovery import fit_without_database
from harness.evaluation import metrics
from harness.evaluation.cache import cached, path_for_key, stable_hash
from harness.evaluation.runner import RunError, RunSpec
from harness.evaluation.scenario import Scenario
from harness.motion import Motion

TEST_SUBJECT_OFFSET = 1000                         # held-out procedural demos use subjects never used in training
_MEMO: dict = {}


def _body() -> BodyModel:
    if "body" not in _MEMO:
        _MEMO["body"] = BodyModel.load()
    return _MEMO["body"]


def _stream(seed: int, name: str) -> np.random.Generator:
    words = [int(b) for b in name.encode()]
    return np.random.default_rng(np.random.SeedSequence([int(seed), *words]))


# --- motions --------------------------------------------------------------------------------------------

def _capture_set(cfg: Scenario) -> list[Motion]:
    from harness.motion.captures import load_capture_set

    db = cfg.database
    key = ("capture", db.capture_dir, db.manifest, db.fps)
    if key not in _MEMO:
        _MEMO[key] = load_capture_set(db.capture_dir, Path(db.capture_dir) / db.manifest, db.fps, body=_body())
    return _MEMO[key]


def _by_class(motions: list[Motion], label: str) -> list[Motion]:
    return [m for m in motions if m.label == label]


def test_motion(run: RunSpec) -> Motion:
    cfg = run.config
    if cfg.database.source == "capture" or cfg.test.split == "captures":
        demos = _by_class(_capture_set(cfg), run.test_class)
        if run.test_demo >= len(demos):
            raise RunError(f"run {run.key}: class {run.test_class!r} has {len(demos)} capture demos")
        return demos[run.test_demo]
    from harness.motion.performer import demonstrations

    rng = _stream(run.seed, "motion")
    return demonstrations(run.test_class, 1, rng, fps=cfg.database.fps,
                          subject=TEST_SUBJECT_OFFSET + run.test_demo)[0]


def training_motions(cfg: Scenario, test: Motion | None) -> list[Motion]:
    """Procedural: ``train_demos`` per class from the training seed, one subject each (0, 1, ...), plus (with
    ``database.with_captures``) every capture demo of another subject than the test motion's.
    Capture: every manifest demo of the scenario's classes except the test demo (leave_one_out) or except the
    test subject's demos (cross_subject)."""
    db = cfg.database
    if db.source == "capture":
        motions = [m for m in _capture_set(cfg) if m.label in cfg.classes]
        if test is not None and cfg.test.split == "leave_one_out":
            motions = [m for m in motions if not (m.demo == test.demo and m.label == test.label)]
        elif test is not None and cfg.test.split == "cross_subject":
            motions = [m for m in motions if m.subject != test.subject]
        return motions
    from harness.motion.performer import demonstrations

    out = []
    for c in cfg.classes:
        rng = _stream(db.seed, f"train/{c}")
        out += [demonstrations(c, 1, rng, fps=db.fps, subject=s)[0] for s in range(db.train_demos)]
    if db.with_captures:
        out += [m for m in _capture_set(cfg)
                if m.label in cfg.classes and (test is None or m.subject != test.subject)]
    return out


def database(cfg: Scenario, test: Motion | None, cache_dir: str | Path) -> MotionDatabase:
    """The run's database, trained once per distinct configuration and cached on disk."""
    db = cfg.database
    key = {"source": db.source, "classes": list(cfg.classes), "states": db.states, "fps": db.fps,
           "cyclic": list(CYCLIC_PRIMITIVES), "format": 1}
    if db.source == "procedural":
        key |= {"train_demos": db.train_demos, "seed": db.seed}
        if db.with_captures:
            key |= {"capture_dir": str(db.capture_dir), "manifest": db.manifest,
                    "with_captures_without_subject": None if test is None else test.subject}
    else:
        # Cross-subject databases depend on the test subject only: one per subject, not one per demo.
        without = [] if test is None else ([test.subject] if cfg.test.split == "cross_subject"
                                           else [test.label, test.demo, test.subject])
        key |= {"capture_dir": str(db.capture_dir), "manifest": db.manifest, "split": cfg.test.split,
                "without": without}
    memo = ("db", stable_hash(key))
    if memo not in _MEMO:
        def build():
            return MotionDatabase(n_states=db.states, cyclic=CYCLIC_PRIMITIVES).fit(training_motions(cfg, test))

        _MEMO[memo] = cached(path_for_key(Path(cache_dir) / "databases", key), build,
                             lambda obj, fh: np.savez(fh, **obj.to_arrays()), MotionDatabase.load)
    return _MEMO[memo]


# --- one run --------------------------------------------------------------------------------------------

def scene_spec(cfg: Scenario, rng: np.random.Generator):
    from harness.scene import CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneSpec

    cam = cfg.camera
    azimuth = float(rng.uniform(0.0, 360.0)) if cam.azimuth == "random" else float(cam.azimuth)
    marker_seed = cfg.markers.seed if cfg.markers.seed is not None else int(rng.integers(2**31))
    occ_seed = cfg.occluders.seed if cfg.occluders.seed is not None else int(rng.integers(2**31))
    preset = cfg.occluders.preset if cfg.occluders.amount > 0 else "none"
    obs = cfg.observation
    return SceneSpec(
        MarkerSpec(cfg.markers.count, marker_seed),
        CameraSpec(distance=cam.distance, azimuth=azimuth, elevation=cam.elevation, fovy=cam.fovy,
                   width=cam.width, height=cam.height, look_at_height=cam.look_at_height, motion=cam.motion,
                   orbit_rate=cam.orbit_rate),
        OccluderSpec(preset, cfg.occluders.amount, occ_seed),
        ObservationSpec(mode=obs.mode, noise_px=obs.noise_px, dropout=obs.dropout, outliers=obs.outliers))


def tracker_config(cfg: Scenario) -> TrackerConfig:
    e = cfg.engine
    return TrackerConfig(particles=e.particles, model_points=e.model_points, model_seed=e.model_seed,
                         init_distance=tuple(e.init_distance))


def _tracker(cfg: Scenario, db: MotionDatabase) -> Tracker:
    tc = tracker_config(cfg)
    key = ("tracker", id(db), tc)
    if key not in _MEMO:
        _MEMO[key] = Tracker(db, _body(), tc)
    return _MEMO[key]


_NAN_RECOGNITION = {"class_pred": "", "correct": np.nan, "frame_accuracy": np.nan, "time_to_correct_s": np.nan,
                    "log_p_true": np.nan}
_NAN_RECOVERY = {k: np.nan for k in (
    "angle_rms_deg", "mpjpe_pose_mm", "mpjpe_cam_mm", "mpjpe_cam17_mm", "pa_mpjpe_mm", "pa_mpjpe17_mm",
    "mpjpe_abs_mm", "base_pos_err_m", "base_depth_err_m", "base_rot_err_deg", "heading_err_deg", "tilt_err_deg",
    "reproj_px")}


def _recognition_scores(post: np.ndarray, classes: list[str], label: str, fps: float) -> dict:
    return metrics.recognition(post, classes, label, fps) | {"log_p_true": metrics.log_p_true(post, classes, label)}


def _recovery_scores(body, qpos_est, truth, obs) -> dict:
    true_cam = metrics.camera_qpos(body, truth.base_pos_cam, truth.base_quat_cam, truth.qpos[:, 7:])
    frame = np.concatenate([np.full(len(i), t) for t, i in enumerate(truth.marker_ids)]).astype(int)
    marker = np.concatenate(truth.marker_ids).astype(int)
    uv = np.concatenate([f[:, :2] for f in obs.flows])
    keep = marker >= 0
    h36m = metrics.h36m_joints(body)
    out = {"angle_rms_deg": metrics.angle_rms_deg(qpos_est[:, 7:], truth.qpos[:, 7:]),
           "mpjpe_pose_mm": metrics.mpjpe_pose_mm(body, qpos_est, true_cam),
           "mpjpe_cam_mm": metrics.mpjpe_camera_mm(body, qpos_est, true_cam),
           "mpjpe_cam17_mm": metrics.mpjpe_camera_mm(body, qpos_est, true_cam, h36m),
           "pa_mpjpe_mm": metrics.pa_mpjpe_mm(body, qpos_est, true_cam),
           "pa_mpjpe17_mm": metrics.pa_mpjpe_mm(body, qpos_est, true_cam, h36m),
           "mpjpe_abs_mm": metrics.mpjpe_absolute_mm(body, qpos_est, true_cam),
           "reproj_px": metrics.reprojection_px(body, qpos_est, truth.markers, obs.intrinsics, frame[keep],
                                                marker[keep], uv[keep])}
    out |= metrics.base_errors(qpos_est[:, :3], qpos_est[:, 3:7], truth.base_pos_cam, truth.base_quat_cam)
    out |= metrics.heading_tilt_errors(qpos_est[:, 3:7], truth.base_quat_cam, truth.camera_rot)
    return out


def run_one(run: RunSpec) -> list[dict]:
    from harness.scene.simulate import simulate

    cfg = run.config
    body = _body()
    motion = test_motion(run)
    db = database(cfg, motion, run.cache_dir)
    if run.test_class not in db.classes_:
        raise RunError(f"run {run.key}: class {run.test_class!r} has no training demonstration in this split")
    scene_rng = _stream(run.seed, "scene")
    obs, truth = simulate(motion, scene_spec(cfg, scene_rng), scene_rng, body)
    common = {"class_true": run.test_class, "n_frames": len(obs), "mean_flows": float(obs.counts[1:].mean()),
              "self_occlusion": float(truth.self_fraction.mean()),
              "obstacle_occlusion": float(truth.obstacle_fraction.mean())}
    classes = list(db.classes_)
    rows = []
    for method in cfg.methods:
        t0 = time.perf_counter()
        if method in ("full", "gt_base"):
            tracker = _tracker(cfg, db)
            tracker.rng = _stream(run.seed, "engine")
            pose = (truth.base_pos_cam, truth.base_quat_cam) if method == "gt_base" else None
            if obs.counts.sum() == 0:
                scores = dict(_NAN_RECOGNITION) | dict(_NAN_RECOVERY)
            else:
                est = tracker.run(obs, base_pose=pose)
                scores = _recognition_scores(est.class_posterior, classes, run.test_class, obs.fps)
                scores |= _recovery_scores(body, est.qpos, truth, obs)
        elif method == "no_database":
            tracker = _tracker(cfg, db)
            angles = fit_without_database(body, tracker.points, obs.intrinsics, obs.flows, truth.base_pos_cam,
                                          truth.base_quat_cam, tracker.config.noise_px, tracker.spread)
            qpos = metrics.camera_qpos(body, truth.base_pos_cam, truth.base_quat_cam, angles)
            scores = dict(_NAN_RECOGNITION) | _recovery_scores(body, qpos, truth, obs)
        elif method == "joint_space":
            post = recognize_features(db, motion_features(motion))
            scores = _recognition_scores(post, classes, run.test_class, motion.fps) | dict(_NAN_RECOVERY)
        else:
            raise RunError(f"run {run.key}: unknown method {method!r}")
        ms = 1e3 * (time.perf_counter() - t0) / max(len(obs), 1)
        rows.append({"method": method} | common | scores | {"ms_per_frame": ms})
    return rows
