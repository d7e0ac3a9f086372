"""Scores of one run: recognition, joint angles, joint positions, baselink pose, reprojection. Arrays in, numbers out.

Conventions: a configuration is ``(T, 57)`` (base position metres, base quaternion w x y z, 50 hinge angles
in radians). "Camera-frame" base poses are the base (pelvis) position and orientation in the OpenCV camera
frame (x right, y down, z forward), which is what the engine estimates. Joint centres are the origins of the
humanoid's bodies (``harness.body.body_origins``).
"""

from __future__ import annotations

import numpy as np

from harness.body import BodyModel, SurfacePoints, body_origins, forward_points
from harness.geometry import angle_between
from harness.pinhole import Intrinsics, project


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
        raise ValueError(f"posteriors must be (T, {len(classes)}) with T >= 1, got {post.shape}")
    if true_label not in classes:
        raise ValueError(f"true label {true_label!r} is not one of the classes {list(classes)}")
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


def mpjpe_relative_mm(body: BodyModel, est_qpos: np.ndarray, true_qpos: np.ndarray) -> float:
    """Root-relative mean per-joint position error, millimetres.

    Joint centres in the base frame (``frame='base'``: the base pose is factored out, so only the angles
    matter); the root itself (always at the origin) is left out of the mean.
    """
    est = body_origins(body, est_qpos, frame="base")[..., 1:, :]
    true = body_origins(body, true_qpos, frame="base")[..., 1:, :]
    return float(1000.0 * np.mean(np.linalg.norm(est - true, axis=-1)))


def camera_qpos(body: BodyModel, base_pos_cam: np.ndarray, base_quat_cam: np.ndarray,
                angles: np.ndarray) -> np.ndarray:
    """Configurations ``(T, 57)`` whose base is the camera-frame pose: FK with ``frame='world'`` then gives
    camera-frame points."""
    return body.qpos(np.asarray(angles, dtype=float), base_pos=base_pos_cam, base_quat=base_quat_cam)


def mpjpe_absolute_mm(body: BodyModel, est_qpos_cam: np.ndarray, true_qpos_cam: np.ndarray) -> float:
    """Absolute mean per-joint position error in the camera frame, millimetres, every joint centre (root
    included); both configurations carry their camera-frame base pose (see ``camera_qpos``)."""
    est = body_origins(body, est_qpos_cam, frame="world")
    true = body_origins(body, true_qpos_cam, frame="world")
    return float(1000.0 * np.mean(np.linalg.norm(est - true, axis=-1)))


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
