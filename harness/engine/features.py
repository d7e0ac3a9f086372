"""The joint-space feature vector the motion database is learned over.

``[theta (50), theta_dot (50), v (3), omega (3)]``: joint angles (rad), their rates (rad/s), and the base's
linear (m/s) and angular (rad/s) velocity expressed in the base frame. Base-frame velocities make the features
independent of where the demonstrator stands and which way it faces, which is what lets one database serve
every viewpoint.
"""

from __future__ import annotations

import numpy as np

from harness.body.model import N_ANGLES
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
