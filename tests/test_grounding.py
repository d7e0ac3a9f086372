"""Grounding (lowest foot point on the floor, the supporting foot still) is the performer's own rule."""

import numpy as np
import pytest

from harness.body import geom_z_range
from harness.body.grounding import foot_geoms, ground
from harness.motion.performer import perform


@pytest.mark.parametrize("label", ["walk", "squat", "kick", "jump"])
def test_grounding_is_the_performers_base_placement(body, label):
    motion, flight = perform(label, np.random.default_rng(5), body=body)
    g = ground(body, motion.angles, motion.base_quat)
    grounded = ~flight
    np.testing.assert_allclose(g.height[grounded], motion.base_pos[grounded, 2], atol=1e-12)
    # Steps between two grounded frames away from any flight are the performer's (it overrides the others).
    if not flight.any():
        np.testing.assert_allclose(g.positions(), motion.base_pos, atol=1e-12)


def test_grounded_poses_touch_the_floor_and_do_not_go_through_it(body, rng):
    angles = body.random_angles(rng, 20, scale=0.3)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (20, 1))
    g = ground(body, angles, quats)
    qpos = body.qpos(angles, base_pos=g.positions(), base_quat=quats)
    low = geom_z_range(body, qpos, foot_geoms(body))[:, :, 0].min(axis=1)
    np.testing.assert_allclose(low, 0.0, atol=1e-12)


def test_a_planted_foot_stays_planted(body):
    """Standing on the right leg (the left one lifted) while the right hip flexes: the base moves back so that
    the right sole (its geom's centre) stays where it is."""
    from harness.body import forward_points

    n = 15
    angles = np.zeros((n, 50))
    angles[:, body.angle_index("lfemur_y")] = -1.2
    angles[:, body.angle_index("ltibia_y")] = 1.2
    angles[:, body.angle_index("rfemur_y")] = np.linspace(0.0, -0.3, n)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    g = ground(body, angles, quats)
    qpos = body.qpos(angles, base_pos=g.positions(), base_quat=quats)
    sole = foot_geoms(body)[2]                           # the right foot's geom: its centre is the sole point
    right = forward_points(body, qpos, body.model.geom_bodyid[[sole]], body.model.geom_pos[[sole]])[:, 0]
    assert np.all(g.support_left < 1e-4)
    np.testing.assert_allclose(right[:, :2] - right[0, :2], 0.0, atol=1e-5)
    assert np.ptp(g.positions()[:, 0]) > 0.05            # the base itself moved
