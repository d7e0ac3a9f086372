"""The timing convention: a flow is a backward difference, and so are the database's velocities.

A body accelerating uniformly: the velocity the features predict for a surface point at frame t equals the
point's backward difference ``(x_t - x_{t-1}) fps`` (what a flow measures), while central differences would lead
it by half a frame (``a dt / 2``)."""

import numpy as np

from harness import geometry
from harness.body import forward_points, sample_surface
from harness.engine.features import ANGLE_RATES, ANGLES, BASE_ANGULAR, BASE_LINEAR, motion_features
from harness.engine.transform import JointGaussians, state_point_distributions
from harness.motion import Motion
from harness.motion.motion import velocities_of


def _accelerating(body, turn: float, bend: float, fps=30.0, n=30):
    """2 m/s^2 along x, ``turn`` rad/s^2 about the vertical, ``bend`` rad/s^2 at the left knee, from rest."""
    t = np.arange(n) / fps
    qpos = np.tile(body.zero_qpos(), (n, 1))
    qpos[:, 0] = 0.5 * 2.0 * t**2
    qpos[:, 3:7] = geometry.exp(np.outer(0.5 * turn * t**2, [0.0, 0.0, 1.0]))
    qpos[:, 7 + body.angle_index("ltibia_y")] = 0.5 * bend * t**2
    return Motion(qpos=qpos, fps=fps, label="test")


def _predicted_world_velocity(body, points, features, qpos):
    """The point velocities the engine predicts from features ``(106,)`` at configuration ``qpos``, in the
    world frame (``x' = J theta' + v + w x x`` in the base frame, rotated by the base orientation)."""
    dist = state_point_distributions(body, JointGaussians.at(features[ANGLES], features[ANGLE_RATES],
                                                             base_linear=features[BASE_LINEAR],
                                                             base_angular=features[BASE_ANGULAR]), points)
    return geometry.rotate(qpos[3:7], dist.vel[0])


def _errors(body, m, points):
    """Largest difference between the predicted point velocities and the 3D backward differences at three
    frames, for the engine's features and for central-difference features."""
    world = forward_points(body, m.qpos, points.body, points.local)
    flow = (world[1:] - world[:-1]) * m.fps
    feats = motion_features(m)
    central = np.concatenate([m.angles, m.velocities.angles, m.velocities.base_linear, m.velocities.base_angular],
                             axis=1)
    frames = (5, 15, 25)
    return ([np.abs(_predicted_world_velocity(body, points, feats[t], m.qpos[t]) - flow[t - 1]).max() for t in frames],
            [np.abs(_predicted_world_velocity(body, points, central[t], m.qpos[t]) - flow[t - 1]).max() for t in frames])


def test_feature_velocities_are_the_flows_backward_differences(body):
    points = sample_surface(body, 40, np.random.default_rng(2))
    # Translation under constant acceleration: exact; central differences lead by a dt / 2 = 3.3 cm/s.
    backward, central = _errors(body, _accelerating(body, 0.0, 0.0), points)
    assert max(backward) < 1e-9
    np.testing.assert_allclose(central, 2.0 / 30.0 / 2.0, rtol=1e-9)
    # With a turn and a bending knee, second-order terms (a chord is not a tangent) remain, far below the
    # half-frame lead of central differences.
    backward, central = _errors(body, _accelerating(body, 0.5, 1.0), points)
    assert max(backward) < 0.3 * min(central)
    m = _accelerating(body, 0.0, 0.0)
    v = velocities_of(m.qpos, m.fps, "backward").base_linear_world
    np.testing.assert_allclose(v[1:, 0], 2.0 * (np.arange(1, 30) - 0.5) / m.fps, rtol=1e-12)
