"""The joint-space feature vector the motion database is learned over.

``[theta (50), theta_dot (50), v (3), omega (3)]``: joint angles (rad), their rates (rad/s), and the base's
linear (m/s) and angular (rad/s) velocity expressed in the base frame. Base-frame velocities make the features
independent of where the demonstrator stands and which way it faces, which is what lets one database serve
every viewpoint.

``mirror_features`` is the same motion performed with the other side: a signed permutation ``M`` of the
features, so a Gaussian ``N(mu, diag(s2))`` of features becomes ``N(M mu, diag(|M| s2))`` exactly.
"""

from __future__ import annotations

import numpy as np

from harness.body.model import MIRROR_INDEX, MIRROR_SIGN, N_ANGLES
from harness.motion.motion import Motion, velocities_of

ANGLES = slice(0, N_ANGLES)
ANGLE_RATES = slice(N_ANGLES, 2 * N_ANGLES)
BASE_LINEAR = slice(2 * N_ANGLES, 2 * N_ANGLES + 3)
BASE_ANGULAR = slice(2 * N_ANGLES + 3, 2 * N_ANGLES + 6)
N_FEATURES = 2 * N_ANGLES + 6


# The one place that fixes the timing convention: a flow is a backward difference, ``(p_t - p_{t-1}) fps`` at
# ``p_t``, so a state's velocities are too. Central differences would put the database half a frame ahead of
# what the camera measures whenever the motion accelerates (tests/test_engine_timing.py).
VELOCITY_SCHEME = "backward"


def motion_features(motion: Motion) -> np.ndarray:
    """``(T, 106)`` features of a motion (velocities by backward finite differences, ``VELOCITY_SCHEME``)."""
    vel = velocities_of(motion.qpos, motion.fps, VELOCITY_SCHEME)
    return np.concatenate([motion.angles, vel.angles, vel.base_linear, vel.base_angular], axis=1)


def measured_features(motion: Motion) -> np.ndarray:
    """``(106,)`` bool: the features a demonstration measures: its measured joints' angles and rates
    (``Motion.measured_joints``) and the base's velocities."""
    joints = motion.measured_joints
    return np.concatenate([joints, joints, np.ones(6, dtype=bool)])


# The mirror through the base frame's sagittal x-z plane (x forward, y to the left, z up), S_b = diag(1, -1, 1):
# angles and their rates by the body's joint mirror; the base's linear velocity reflected, S_b v = (vx, -vy, vz);
# its angular velocity, a pseudovector, det(S_b) S_b w = (-wx, wy, -wz) (roll and yaw rates change sides).
_MIRROR_INDEX = np.concatenate([MIRROR_INDEX, N_ANGLES + MIRROR_INDEX, np.arange(2 * N_ANGLES, N_FEATURES)])
_MIRROR_SIGN = np.concatenate([MIRROR_SIGN, MIRROR_SIGN, [1.0, -1.0, 1.0], [-1.0, 1.0, -1.0]])


def mirror_features(features: np.ndarray) -> np.ndarray:
    """Features ``(..., 106)`` of the mirror-image motion (the other side), or the means of mirrored states."""
    return np.asarray(features)[..., _MIRROR_INDEX] * _MIRROR_SIGN


def mirror_variances(variances: np.ndarray) -> np.ndarray:
    """Diagonal feature variances ``(..., 106)`` of the mirror-image motion (signs do not change a variance)."""
    return np.asarray(variances)[..., _MIRROR_INDEX]
