"""Camera placement relative to the subject, its trajectory, and its own velocity.

Placement (see docs/scene.md): the look-at point is the mean of the subject's base xy over the motion, at
``look_at_height``. The camera sits ``distance`` metres from it, at ``azimuth`` degrees about world z from the
subject's initial heading (0 = in front of the subject, 90 = on its left) and ``elevation`` degrees above the
horizontal. "orbit" adds ``orbit_rate * t`` to the azimuth; "follow" translates the camera (and its look-at
point) with the subject's base xy, keeping its orientation, like a robot following the subject.

Rotations are world-from-camera with OpenCV camera axes as columns: x right, y down, z forward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness import geometry
from harness.motion.motion import Motion
from harness.pinhole import MUJOCO_TO_OPENCV, Intrinsics
from harness.scene.spec import CameraSpec, SceneError

WORLD_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class CameraTrajectory:
    """A camera over ``T`` frames.

    intrinsics: the pinhole. pos: ``(T, 3)`` centre, world, metres. rot: ``(T, 3, 3)`` world-from-camera
    (OpenCV axes as columns). look_at: ``(T, 3)`` the point it aims at. moving: whether pos/rot change.
    """

    intrinsics: Intrinsics
    pos: np.ndarray
    rot: np.ndarray
    look_at: np.ndarray
    moving: bool

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``(T, N, 3)`` to camera-frame points ``(T, N, 3)``: ``R_t^T (p - c_t)``."""
        return np.einsum("tji,tnj->tni", self.rot, np.asarray(points, float) - self.pos[:, None, :])

    def mujoco_quat(self) -> np.ndarray:
        """``(T, 4)`` wxyz world-from-camera in MuJoCo's camera axes (x right, y up, looking along -z)."""
        return geometry.from_matrix(self.rot @ MUJOCO_TO_OPENCV)


def look_at_rotation(pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World-from-camera rotations ``(T, 3, 3)`` of cameras at ``pos`` aiming at ``target`` (both ``(T, 3)``),
    with the image's x axis horizontal (no roll)."""
    fwd = np.asarray(target, float) - np.asarray(pos, float)
    fwd /= np.linalg.norm(fwd, axis=-1, keepdims=True)
    right = np.cross(fwd, WORLD_UP)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], axis=-1)


def camera_trajectory(motion: Motion, spec: CameraSpec) -> CameraTrajectory:
    """Place the camera of ``spec`` for every frame of ``motion``."""
    intr = Intrinsics.from_fov(spec.fovy, spec.width, spec.height)
    base_xy = motion.base_pos[:, :2]
    heading0 = float(geometry.heading(motion.base_quat[0]))
    t = motion.times
    centre = np.append(base_xy.mean(axis=0), spec.look_at_height)
    look_at = np.repeat(centre[None], len(t), axis=0)
    azimuth = heading0 + np.deg2rad(spec.azimuth) + np.zeros(len(t))
    if spec.motion == "orbit":
        azimuth = azimuth + np.deg2rad(spec.orbit_rate) * t
    if spec.motion == "follow":
        look_at[:, :2] = base_xy
    el = np.deg2rad(spec.elevation)
    offset = spec.distance * np.stack([np.cos(el) * np.cos(azimuth), np.cos(el) * np.sin(azimuth),
                                       np.full(len(t), np.sin(el))], axis=1)
    pos = look_at + offset
    low = np.flatnonzero(pos[:, 2] <= 0.0)
    if len(low):
        raise SceneError(f"camera.elevation={spec.elevation!r}, camera.look_at_height={spec.look_at_height!r}: "
                         f"the camera is at or below the floor (z={pos[low[0], 2]:.2f} m at frame {low[0]})")
    moving = spec.motion == "follow" or (spec.motion == "orbit" and spec.orbit_rate != 0.0)
    return CameraTrajectory(intr, pos, look_at_rotation(pos, look_at), look_at, moving)


def camera_velocity(traj: CameraTrajectory, fps: float) -> np.ndarray:
    """Camera velocity in its own frame, ``(T, 6)``: linear (m/s) then angular (rad/s), OpenCV axes.

    Central differences inside, one-sided at the ends (``geometry.finite_difference``); the angular rate is
    ``log(R_a^T R_b) / dt_ab`` on the rotation group (``geometry.body_angular_velocity``).
    """
    dt = 1.0 / fps
    lin = np.einsum("tji,tj->ti", traj.rot, geometry.finite_difference(traj.pos, dt))
    ang = geometry.body_angular_velocity(geometry.from_matrix(traj.rot), dt)
    return np.concatenate([lin, ang], axis=1)
