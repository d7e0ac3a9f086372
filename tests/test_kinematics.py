import mujoco
import numpy as np
import pytest

from harness.body import (BodyModel, body_origins, forward_points, forward_points_and_jacobians, point_velocities,
                          sample_surface)
from harness.body.model import DEFAULT_MODEL_PATH


@pytest.fixture(scope="module")
def points(body):
    return sample_surface(body, 60, np.random.default_rng(7))


def _model_with_sites(body, points):
    """The same humanoid with a MuJoCo site at every sample point (an independent FK)."""
    spec = mujoco.MjSpec.from_file(str(DEFAULT_MODEL_PATH))
    for i, (b, p) in enumerate(zip(points.body, points.local)):
        spec.body(body.body_names[b]).add_site(name=f"p{i}", pos=p)
    return spec.compile()


@pytest.mark.parametrize("frame", ["world", "base"])
def test_fk_matches_mujoco_sites(body, points, rng, frame):
    m = _model_with_sites(body, points)
    d = mujoco.MjData(m)
    qpos = body.qpos(body.random_angles(rng, 10), base_pos=rng.normal(size=(10, 3)))
    quat = rng.normal(size=(10, 4))
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    ours = forward_points(body, qpos, points.body, points.local, frame=frame)
    for t, q in enumerate(qpos):
        d.qpos[:] = q
        if frame == "base":
            d.qpos[:7] = [0, 0, 0, 1, 0, 0, 0]
        mujoco.mj_kinematics(m, d)
        site_xpos = np.array([d.site(f"p{i}").xpos for i in range(len(points))])
        np.testing.assert_allclose(ours[t], site_xpos, atol=1e-9, rtol=0)


@pytest.mark.parametrize("frame", ["world", "base"])
def test_jacobian_matches_central_differences(body, points, rng, frame):
    for _ in range(3):
        q = body.qpos(body.random_angles(rng, scale=0.8), base_pos=rng.normal(size=3))
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
        _, jac = forward_points_and_jacobians(body, q, points.body, points.local, frame=frame)
        fd = np.empty_like(jac)
        h = 1e-6
        for k, idx in enumerate(body.angle_qpos_index):
            qp, qm = q.copy(), q.copy()
            qp[idx] += h
            qm[idx] -= h
            fd[:, :, k] = (forward_points(body, qp, points.body, points.local, frame)
                           - forward_points(body, qm, points.body, points.local, frame)) / (2 * h)
        rel = np.linalg.norm(jac - fd) / np.linalg.norm(fd)
        assert rel < 1e-6


def test_jacobian_equals_mj_jac_at_the_point(body, points, rng):
    q = body.qpos(body.random_angles(rng))
    pos, jac = forward_points_and_jacobians(body, q, points.body, points.local)
    m, d = body.model, mujoco.MjData(body.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    jacp = np.empty((3, m.nv))
    for i in range(len(points)):
        mujoco.mj_jac(m, d, jacp, None, pos[i], int(points.body[i]))
        np.testing.assert_allclose(jac[i], jacp[:, body.angle_dof_index], atol=1e-12)


def _tilted_body(rng):
    """humanoid56 with every body turned in its parent and every hinge's anchor moved off its body's origin, so
    that the compiled walk of the tree is checked on what the humanoid's own file leaves at zero."""
    spec = mujoco.MjSpec.from_file(str(DEFAULT_MODEL_PATH))
    for b in spec.bodies[2:]:
        quat = np.array([1.0, *rng.normal(0, 0.3, 3)])
        b.quat = quat / np.linalg.norm(quat)
        for j in b.joints:
            j.pos = rng.normal(0, 0.05, 3)
    return BodyModel(spec.compile())


@pytest.mark.parametrize("frame", ["world", "base"])
@pytest.mark.parametrize("tilted", [False, True])
def test_compiled_tree_matches_mujoco(body, points, rng, frame, tilted):
    """Positions and Jacobians of the compiled tree (``harness.body.tree``) against MuJoCo's ``mj_kinematics``
    and ``mj_jac`` at each point, in both frames, at random angles and base poses (quaternions not normalised:
    MuJoCo normalises them)."""
    body = _tilted_body(rng) if tilted else body
    m, d = body.model, mujoco.MjData(body.model)
    qpos = body.qpos(body.random_angles(rng, 5), base_pos=rng.normal(size=(5, 3)), base_quat=rng.normal(size=(5, 4)))
    pos, jac = forward_points_and_jacobians(body, qpos, points.body, points.local, frame=frame)
    jacp = np.empty((3, m.nv))
    for t, q in enumerate(qpos):
        d.qpos[:] = q
        if frame == "base":
            d.qpos[:7] = [0, 0, 0, 1, 0, 0, 0]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mj_pos = d.xpos[points.body] + np.einsum("pij,pj->pi", d.xmat[points.body].reshape(-1, 3, 3), points.local)
        np.testing.assert_allclose(pos[t], mj_pos, rtol=0, atol=1e-12)
        for i in range(len(points)):
            mujoco.mj_jac(m, d, jacp, None, mj_pos[i], int(points.body[i]))
            np.testing.assert_allclose(jac[t, i], jacp[:, body.angle_dof_index], rtol=0, atol=1e-12)


def test_batch_equals_single(body, points, rng):
    qpos = body.qpos(body.random_angles(rng, 4))
    pos, jac = forward_points_and_jacobians(body, qpos, points.body, points.local)
    p1, j1 = forward_points_and_jacobians(body, qpos[2], points.body, points.local)
    assert np.array_equal(pos[2], p1) and np.array_equal(jac[2], j1)


def test_world_is_base_moved_by_the_base_pose(body, points, rng):
    q = body.qpos(body.random_angles(rng), base_pos=[0.3, -1.0, 0.9], base_quat=[0.8, 0.2, -0.1, 0.55])
    q[3:7] /= np.linalg.norm(q[3:7])
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, q[3:7])
    world = forward_points(body, q, points.body, points.local, "world")
    base = forward_points(body, q, points.body, points.local, "base")
    np.testing.assert_allclose(world, base @ rot.reshape(3, 3).T + q[:3], atol=1e-12)


def test_point_velocities_match_finite_differences(body, points, rng):
    """Velocities in the base frame against differences of world positions along a moving trajectory."""
    m = body.model
    q0 = body.qpos(body.random_angles(rng, scale=0.7), base_pos=[0.2, 0.1, 1.0])
    qvel = rng.normal(size=56)
    h = 1e-6

    def at(t):
        q = q0.copy()
        mujoco.mj_integratePos(m, q, qvel, t)
        return q

    world = lambda t: forward_points(body, at(t), points.body, points.local, "world")  # noqa: E731
    v_world = (world(h) - world(-h)) / (2 * h)
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, q0[3:7])
    rot = rot.reshape(3, 3)
    v_base_fd = v_world @ rot            # R^T v for each row
    # MuJoCo's free-joint qvel: linear velocity in world, angular velocity in the base frame.
    lin_base = rot.T @ qvel[:3]
    ours = point_velocities(body, q0, qvel[6:], lin_base, qvel[3:6], points.body, points.local)
    np.testing.assert_allclose(ours, v_base_fd, atol=1e-6)


def test_body_origins_are_joint_centres(body):
    origins = body_origins(body, body.zero_qpos())
    ltibia = body.body_id("ltibia") - 1
    assert np.allclose(origins[ltibia], [0.0, 0.09, 0.47])
    assert np.allclose(origins[0], [0.0, 0.0, 0.95])


def test_bad_qpos_shape(body, points):
    with pytest.raises(ValueError, match="qpos must have shape"):
        forward_points(body, np.zeros((3, 50)), points.body, points.local)
    with pytest.raises(ValueError, match="frame must be one of"):
        forward_points(body, body.zero_qpos(), points.body, points.local, frame="camera")
