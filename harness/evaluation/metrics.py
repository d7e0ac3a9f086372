"""Scores of one run: recognition, joint angles, joint positions, baselink pose, reprojection. Arrays in, numbers out.

Conventions: a configuration is ``(T, 57)`` (base position metres, base quaternion w x y z, 50 hinge angles
in radians). "Camera-frame" base poses are the base (pelvis) position and orientation in the OpenCV camera
frame (x right, y down, z forward), which is what the engine estimates. Joint centres are the origins of the
humanoid's bodies (``harness.body.body_origins``). The MPJPE functions take the estimate's body and, as
``true_body``, the observed subject's (default: the same body): a scaled subject's true joints are its own.
"""

from __future__ import annotations

import numpy as np

from harness.body import BodyModel, SurfacePoints, body_origins, forward_points
from harness.errors import HarnessError
from harness.geometry import angle_between, conjugate, from_matrix, multiply
from harness.pinhole import Intrinsics, project


class MetricError(HarnessError, ValueError):
    """Inputs a metric cannot score (wrong shapes, a label that is not a class)."""


def recognition(posteriors: np.ndarray, classes: list[str] | tuple[str, ...], true_label: str,
                fps: float) -> dict:
    """Recognition scores from per-frame class posteriors ``(T, C)`` (rows sum to one).

    Returns ``class_pred`` (argmax of the last frame), ``correct`` (1 if it is the true label, else 0),
    ``frame_accuracy`` (fraction of frames whose argmax is the true label) and ``time_to_correct_s``: the time
    ``t / fps`` of the first frame ``t`` from which the argmax stays the true label to the end (NaN if the last
    frame is wrong; 0.0 if right from the first frame).
    """
    post = np.asarray(posteriors, dtype=float)
    if post.ndim != 2 or post.shape[1] != len(classes) or len(post) == 0:
        raise MetricError(f"posteriors must be (T, {len(classes)}) with T >= 1, got {post.shape}")
    if true_label not in classes:
        raise MetricError(f"true label {true_label!r} is not one of the classes {list(classes)}")
    hit = np.argmax(post, axis=1) == list(classes).index(true_label)
    wrong = np.flatnonzero(~hit)
    if hit[-1]:
        t_correct = (wrong[-1] + 1 if len(wrong) else 0) / float(fps)
    else:
        t_correct = float("nan")
    return {"class_pred": classes[int(np.argmax(post[-1]))], "correct": int(hit[-1]),
            "frame_accuracy": float(hit.mean()), "time_to_correct_s": float(t_correct)}


def angle_rms_deg(est_angles: np.ndarray, true_angles: np.ndarray) -> float:
    """Root-mean-square joint-angle error over all frames and hinges, degrees (differences wrapped to ±180)."""
    d = np.asarray(est_angles, dtype=float) - np.asarray(true_angles, dtype=float)
    d = (d + np.pi) % (2 * np.pi) - np.pi
    return float(np.rad2deg(np.sqrt(np.mean(d**2))))


# Human3.6M's 17 joints (protocol order) on humanoid56 bodies: hip, right leg, left leg, spine, thorax, neck,
# head, left arm, right arm. Human3.6M's "spine" sits between hip and thorax (upperback, 0.19 m above the
# pelvis at the zero pose), its "thorax" at the neck's base (lowerneck), "neck/nose" at upperneck, "head" at the
# head body's origin.
H36M_BODIES = ("pelvis", "rfemur", "rtibia", "rfoot", "lfemur", "ltibia", "lfoot", "upperback", "lowerneck",
               "upperneck", "head", "lhumerus", "lradius", "lwrist", "rhumerus", "rradius", "rwrist")
LOG_P_FLOOR = 1e-15     # log_p_true is clipped at log(1e-15) = -34.5, as scikit-learn's log loss does


def h36m_joints(body: BodyModel) -> np.ndarray:
    """Indices ``(17,)`` into ``body_origins``'s joint axis (0 = root) of the Human3.6M joints."""
    return np.array([body.body_id(name) - 1 for name in H36M_BODIES])


def log_p_true(posteriors: np.ndarray, classes: list[str] | tuple[str, ...], true_label: str) -> float:
    """Natural log of the last frame's posterior of the true class, clipped at ``log(LOG_P_FLOOR)``: a
    continuous score beside the 0/1 accuracy (0 = certain and right)."""
    post = np.asarray(posteriors, dtype=float)
    if true_label not in classes:
        raise MetricError(f"true label {true_label!r} is not one of the classes {list(classes)}")
    return float(np.log(max(post[-1, list(classes).index(true_label)], LOG_P_FLOOR)))


def mpjpe_pose_mm(body: BodyModel, est_qpos: np.ndarray, true_qpos: np.ndarray,
                  true_body: BodyModel | None = None) -> float:
    """Pose-only mean per-joint position error, millimetres.

    Joint centres in the base (pelvis) frame: the base pose is factored out, so only the angles matter and a
    body estimated facing backwards with the right angles scores 0. The root (always at the origin) is left
    out of the mean.
    """
    return _mpjpe_pose(body_origins(body, est_qpos, frame="base"),
                       body_origins(true_body or body, true_qpos, frame="base"))


def camera_qpos(body: BodyModel, base_pos_cam: np.ndarray, base_quat_cam: np.ndarray,
                angles: np.ndarray) -> np.ndarray:
    """Configurations ``(T, 57)`` whose base is the camera-frame pose: FK with ``frame='world'`` then gives
    camera-frame points."""
    return body.qpos(np.asarray(angles, dtype=float), base_pos=base_pos_cam, base_quat=base_quat_cam)


def mpjpe_absolute_mm(body: BodyModel, est_qpos_cam: np.ndarray, true_qpos_cam: np.ndarray,
                      true_body: BodyModel | None = None) -> float:
    """Absolute mean per-joint position error in the camera frame, millimetres, every joint centre (root
    included); both configurations carry their camera-frame base pose (see ``camera_qpos``)."""
    return _mean_distance_mm(body_origins(body, est_qpos_cam, frame="world"),
                             body_origins(true_body or body, true_qpos_cam, frame="world"))


def mpjpe_camera_mm(body: BodyModel, est_qpos_cam: np.ndarray, true_qpos_cam: np.ndarray,
                    joints: np.ndarray | None = None, true_body: BodyModel | None = None) -> float:
    """Human3.6M protocol 1, millimetres: joint centres in the camera frame with each skeleton's root
    (pelvis) subtracted, so the base orientation counts and the base translation does not.

    ``joints``: indices into the joint axis (default: every non-root joint, 24). With ``h36m_joints`` the
    mean runs over the 17 joints, the root included at zero error, as Human3.6M's evaluation code does.
    """
    return _mpjpe_camera(body_origins(body, est_qpos_cam, frame="world"),
                         body_origins(true_body or body, true_qpos_cam, frame="world"), joints)


def procrustes_align(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Per frame, the similarity transform (rotation, uniform scale, translation) of ``est`` ``(T, J, 3)`` that
    best fits ``true`` in least squares (Umeyama, 1991; reflections excluded); returns the aligned ``est``."""
    est, true = np.asarray(est, dtype=float), np.asarray(true, dtype=float)
    mu_e, mu_t = est.mean(axis=-2, keepdims=True), true.mean(axis=-2, keepdims=True)
    e, t = est - mu_e, true - mu_t
    u, s, vt = np.linalg.svd(np.swapaxes(e, -1, -2) @ t)          # H = E^T T = U S V^T
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    s[..., -1] *= d
    u[..., :, -1] *= d[..., None]
    rot = u @ vt                                                    # row-vector form: aligned = e @ rot
    scale = s.sum(axis=-1) / np.maximum(np.sum(e * e, axis=(-2, -1)), 1e-300)
    return scale[..., None, None] * (e @ rot) + mu_t


def pa_mpjpe_mm(body: BodyModel, est_qpos_cam: np.ndarray, true_qpos_cam: np.ndarray,
                joints: np.ndarray | None = None, true_body: BodyModel | None = None) -> float:
    """Human3.6M protocol 2, millimetres: mean joint error after a per-frame similarity Procrustes alignment
    of the estimated joints onto the true ones, over ``joints`` (default: all 25 joint centres, root
    included; ``h36m_joints`` for the 17)."""
    return _pa_mpjpe(body_origins(body, est_qpos_cam, frame="world"),
                     body_origins(true_body or body, true_qpos_cam, frame="world"), joints)


def joint_errors_mm(est_world: np.ndarray, true_world: np.ndarray, est_base: np.ndarray, true_base: np.ndarray,
                    h36m: np.ndarray) -> dict:
    """The joint-position columns from joint centres computed once (``body_origins`` of the estimate and of
    the truth, camera frame ``world`` and base frame ``base``, ``(T, J, 3)``), the same numbers as
    ``mpjpe_pose_mm``, ``mpjpe_camera_mm``, ``pa_mpjpe_mm`` (all joints and ``h36m``) and ``mpjpe_absolute_mm``:
    each of those computes both configurations' joints again, which made scoring a run's estimates cost more
    than recognising it from joint angles."""
    return {"mpjpe_pose_mm": _mpjpe_pose(est_base, true_base),
            "mpjpe_cam_mm": _mpjpe_camera(est_world, true_world),
            "mpjpe_cam17_mm": _mpjpe_camera(est_world, true_world, h36m),
            "pa_mpjpe_mm": _pa_mpjpe(est_world, true_world),
            "pa_mpjpe17_mm": _pa_mpjpe(est_world, true_world, h36m),
            "mpjpe_abs_mm": _mean_distance_mm(est_world, true_world)}


def _mean_distance_mm(est: np.ndarray, true: np.ndarray) -> float:
    return float(1000.0 * np.mean(np.linalg.norm(est - true, axis=-1)))


def _mpjpe_pose(est_base: np.ndarray, true_base: np.ndarray) -> float:
    return _mean_distance_mm(est_base[..., 1:, :], true_base[..., 1:, :])


def _mpjpe_camera(est: np.ndarray, true: np.ndarray, joints: np.ndarray | None = None) -> float:
    est, true = est - est[..., :1, :], true - true[..., :1, :]
    sel = np.arange(1, est.shape[-2]) if joints is None else np.asarray(joints)
    return _mean_distance_mm(est[..., sel, :], true[..., sel, :])


def _pa_mpjpe(est: np.ndarray, true: np.ndarray, joints: np.ndarray | None = None) -> float:
    if joints is not None:
        est, true = est[..., joints, :], true[..., joints, :]
    est, true = est.reshape(-1, *est.shape[-2:]), true.reshape(-1, *true.shape[-2:])
    return _mean_distance_mm(procrustes_align(est, true), true)


def base_errors(est_pos: np.ndarray, est_quat: np.ndarray, true_pos: np.ndarray, true_quat: np.ndarray) -> dict:
    """Baselink errors averaged over frames: ``base_pos_err_m`` (Euclidean, m), ``base_depth_err_m`` (absolute
    camera-z difference, m) and ``base_rot_err_deg`` (angle of the relative rotation, degrees).

    Positions ``(T, 3)`` and quaternions ``(T, 4)`` in the camera frame.
    """
    d = np.asarray(est_pos, dtype=float) - np.asarray(true_pos, dtype=float)
    rot = angle_between(np.asarray(est_quat, dtype=float), np.asarray(true_quat, dtype=float))
    return {"base_pos_err_m": float(np.mean(np.linalg.norm(d, axis=-1))),
            "base_depth_err_m": float(np.mean(np.abs(d[..., 2]))),
            "base_rot_err_deg": float(np.rad2deg(np.mean(rot)))}


def heading_tilt_errors(est_quat_cam: np.ndarray, true_quat_cam: np.ndarray, camera_rot: np.ndarray) -> dict:
    """The baselink orientation error split about the world vertical, degrees averaged over frames.

    With world orientations ``R = C R_cam`` (``camera_rot`` ``(T, 3, 3)``: world from camera), the relative
    rotation ``D = R_est R_true^T`` (world frame) is decomposed as ``D = D_swing D_twist`` with ``D_twist`` a
    rotation about world z: ``heading_err_deg`` is the angle of the twist (the yaw error, in [0, 180]),
    ``tilt_err_deg`` that of the swing (the error of the body's up axis).
    """
    twist_angle, swing_angle = _twist_swing(est_quat_cam, true_quat_cam, camera_rot)
    return {"heading_err_deg": float(np.rad2deg(np.mean(twist_angle))),
            "tilt_err_deg": float(np.rad2deg(np.mean(swing_angle)))}


def heading_error_curve(est_quat_cam: np.ndarray, true_quat_cam: np.ndarray, camera_rot: np.ndarray,
                        points: int) -> list[float]:
    """The heading error (deg, ``heading_tilt_errors``' twist angle) at frames ``round(k (T - 1) / (points -
    1))``, ``k = 0..points-1``: how the baselink's heading settles over the clip."""
    twist, _ = _twist_swing(est_quat_cam, true_quat_cam, camera_rot)
    frames = np.round(np.linspace(0, len(twist) - 1, points)).astype(int)
    return [float(v) for v in np.rad2deg(twist[frames])]


def _twist_swing(est_quat_cam: np.ndarray, true_quat_cam: np.ndarray, camera_rot: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the twist (about world z) and swing angles (rad) of ``D = R_est R_true^T`` (world frame)."""
    cam = from_matrix(np.asarray(camera_rot, dtype=float))
    est_w = multiply(cam, np.asarray(est_quat_cam, dtype=float))
    true_w = multiply(cam, np.asarray(true_quat_cam, dtype=float))
    rel = multiply(est_w, conjugate(true_w))
    # Twist about z: the quaternion's scalar and z parts, renormalised (at a half-turn swing it is undefined
    # and taken as no twist). The swing D twist^-1 then has scalar part hypot(w, z) and vector norm
    # hypot(x, y); atan2 keeps both angles accurate near zero.
    w, x, y, z = np.moveaxis(rel, -1, 0)
    return 2.0 * np.arctan2(np.abs(z), np.abs(w)), 2.0 * np.arctan2(np.hypot(x, y), np.hypot(w, z))


def heading_twin_error(est_quat_cam: np.ndarray, true_quat_cam: np.ndarray, camera_rot: np.ndarray) -> dict:
    """``heading_err_twin_deg``: the heading error up to the exact twin, degrees averaged over frames.

    The twin of the true orientation, ``S R_true S_b`` (``harness.engine.track.twin`` without gravity: depth
    reflected through the camera's image plane, the body mirrored left to right), gives the same unlabeled
    points under orthographic projection: no flow tells the two apart. Per frame the error is the smaller
    of the heading error (``heading_tilt_errors``) against the truth and against its twin; seen from the
    side the two coincide, from the front or back they face opposite ways. So ``heading_err_deg`` minus this
    is what the twin ambiguity costs (the information limit), and what remains is the tracker's own error.
    Quaternions ``(T, 4)`` wxyz in the camera frame, ``camera_rot`` ``(T, 3, 3)`` world from camera.
    """
    from harness.engine.track import twin

    true_quat_cam = np.asarray(true_quat_cam, dtype=float).reshape(-1, 4)
    direct, _ = _twist_swing(est_quat_cam, true_quat_cam, camera_rot)
    mirrored, _ = _twist_swing(est_quat_cam, twin(true_quat_cam), camera_rot)
    return {"heading_err_twin_deg": float(np.rad2deg(np.mean(np.minimum(direct, mirrored))))}


def reprojection_px(body: BodyModel, est_qpos_cam: np.ndarray, markers: SurfacePoints, intrinsics: Intrinsics,
                    frame: np.ndarray, marker: np.ndarray, observed_uv: np.ndarray) -> float:
    """Mean pixel distance between observed visible markers and their projection under the estimate.

    est_qpos_cam: ``(T, 57)`` estimated configurations with camera-frame base. markers: the scene's markers.
    frame, marker: ``(N,)`` int, the frame and marker id of each observed point (ground truth knows them;
    the engine does not). observed_uv: ``(N, 2)`` observed pixels. NaN when nothing was observed.
    """
    frame, marker = np.asarray(frame, dtype=int), np.asarray(marker, dtype=int)
    if len(frame) == 0:
        return float("nan")
    used, slot = np.unique(frame, return_inverse=True)     # only the frames that have observations
    qpos = np.asarray(est_qpos_cam, dtype=float)[used]
    pts = forward_points(body, qpos, markers.body, markers.local, frame="world")
    uv = project(intrinsics, pts[slot, marker])
    return float(np.mean(np.linalg.norm(uv - np.asarray(observed_uv, dtype=float), axis=-1)))
