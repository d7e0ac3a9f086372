"""What the engine recovers: the ``Estimate`` every evaluation method returns, and the offline smoother."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from harness import geometry


@dataclass(frozen=True)
class Estimate:
    """A method's estimate of one sequence of ``T`` frames.

    classes ``(C,)``; qpos ``(T, 57)``: base pose in the camera frame (OpenCV axes) and the 50 angles, or None for
    a method that does not recover the body; class_posterior ``(T, C)``, or None for a method that does not
    recognise. The engine's estimates also carry: joint_posterior ``(T, C, K)`` over (primitive, state);
    filter_pos ``(T, 3)`` / filter_quat ``(T, 4)``: the leading track's filter estimate before refinement;
    n_tracks ``(T,)``; leader ``(T,)``: the origin of the leading track; ms_per_frame ``(T,)``; timing: mean ms per
    frame of each stage; raw_log_posterior ``(T, C)``: the log class posterior before calibration
    (``harness.engine.confidence``); offline: the hindsight estimate of the same run (``records.offline_estimate``), for
    evaluation only; reproduction: a reproduced motion (``harness.motion.Motion``) when the method reproduces.
    """

    classes: np.ndarray
    qpos: np.ndarray | None = None
    class_posterior: np.ndarray | None = None
    joint_posterior: np.ndarray | None = None
    filter_pos: np.ndarray | None = None
    filter_quat: np.ndarray | None = None
    n_tracks: np.ndarray | None = None
    leader: np.ndarray | None = None
    ms_per_frame: np.ndarray | None = None
    timing: dict = field(default_factory=dict)
    raw_log_posterior: np.ndarray | None = None
    offline: "Estimate | None" = None
    reproduction: object | None = None

    @property
    def predicted(self) -> str:
        """The most probable class at the last frame."""
        return str(self.classes[int(np.argmax(self.class_posterior[-1]))])


def smooth_trajectory(qpos: np.ndarray, sigma_frames: float) -> np.ndarray:
    """Configurations ``(T, 57)`` smoothed by a Gaussian of ``sigma_frames`` frames: positions and angles
    component-wise, orientations as sign-aligned quaternions renormalised (a fixed-interval smoother)."""
    qpos = np.array(qpos, dtype=float)
    if sigma_frames <= 0 or len(qpos) < 2:
        return qpos
    quat = qpos[:, 3:7].copy()
    flip = np.cumprod(np.where(np.sum(quat[1:] * quat[:-1], axis=1) < 0, -1.0, 1.0))
    quat[1:] *= flip[:, None]
    out = gaussian_filter1d(qpos, sigma_frames, axis=0, mode="nearest")
    out[:, 3:7] = geometry.normalize(gaussian_filter1d(quat, sigma_frames, axis=0, mode="nearest"))
    return out
