import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from harness import geometry as g
from harness.pinhole import CameraError, Intrinsics, in_image, project, projection_jacobian


def _random_quats(rng, n):
    return g.normalize(rng.normal(size=(n, 4)))


def _scipy(q):
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def test_matrix_and_rotation_match_scipy(rng):
    q = _random_quats(rng, 50)
    v = rng.normal(size=(50, 3))
    np.testing.assert_allclose(g.to_matrix(q), _scipy(q).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(g.rotate(q, v), _scipy(q).apply(v), atol=1e-12)
    back = g.from_matrix(g.to_matrix(q))
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-12)


def test_multiply_composes_like_mujoco(rng):
    a, b = _random_quats(rng, 2)
    res = np.empty(4)
    mujoco.mju_mulQuat(res, a, b)
    np.testing.assert_allclose(g.multiply(a, b), res, atol=1e-15)


@pytest.mark.parametrize("shape_a, shape_b", [((6, 4), (6, 4)), ((6, 4), (4,)), ((1, 4), (6, 4)),
                                              ((2, 3, 4), (3, 4)), ((2, 1, 4), (1, 3, 4)), ((0, 4), (4,))])
def test_multiply_and_matrices_broadcast_like_numpy(rng, shape_a, shape_b):
    """The compiled product and matrices over any leading axes: each element is MuJoCo's product of the
    broadcast pair, and each matrix scipy's, also for rows taken with a stride."""
    a = g.normalize(rng.normal(size=shape_a))
    b = g.normalize(rng.normal(size=(*shape_b[:-1], 8)))[..., ::2]          # not contiguous
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    out = g.multiply(a, b)
    shape = np.broadcast_shapes(a.shape, b.shape)
    assert out.shape == shape
    for i in np.ndindex(shape[:-1]):
        ai, bi = np.broadcast_to(a, shape)[i], np.broadcast_to(b, shape)[i]
        res = np.empty(4)
        mujoco.mju_mulQuat(res, np.ascontiguousarray(ai), np.ascontiguousarray(bi))
        np.testing.assert_allclose(out[i], res, atol=1e-15)
    np.testing.assert_allclose(g.to_matrix(b), _scipy(b).as_matrix() if b.size else np.empty((0, 3, 3)),
                               atol=1e-12)


def test_exp_log_roundtrip_and_scipy(rng):
    rv = rng.normal(size=(40, 3))
    rv *= (np.pi * 0.99 / np.maximum(np.linalg.norm(rv, axis=1), np.pi))[:, None]  # angles below pi
    q = g.exp(rv)
    np.testing.assert_allclose(g.log(q), rv, atol=1e-10)
    np.testing.assert_allclose(np.abs(np.sum(q * _scipy_q(rv), axis=1)), 1.0, atol=1e-12)
    tiny = np.array([[1e-12, 0, 0]])
    np.testing.assert_allclose(g.log(g.exp(tiny)), tiny, atol=1e-20)


def _scipy_q(rv):
    xyzw = Rotation.from_rotvec(rv).as_quat()
    return xyzw[:, [3, 0, 1, 2]]


def test_slerp_endpoints_and_midpoint(rng):
    a, b = _random_quats(rng, 2)
    np.testing.assert_allclose(np.abs(g.slerp(a, b, 0.0) @ a), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(g.slerp(a, b, 1.0) @ b), 1.0, atol=1e-12)
    mid = g.slerp(a, b, 0.5)
    assert np.isclose(g.angle_between(a, mid), g.angle_between(mid, b), atol=1e-12)


def test_weighted_mean_matches_scipy_and_ignores_sign(rng):
    base = _random_quats(rng, 1)[0]
    qs = g.normalize(base + 0.1 * rng.normal(size=(30, 4)))
    w = rng.random(30)
    flipped = qs * np.where(rng.random(30) < 0.5, -1, 1)[:, None]
    ours = g.weighted_mean(flipped, w)
    ref = _scipy(qs).mean(weights=w).as_quat()[[3, 0, 1, 2]]
    assert abs(ours @ ref) > 1 - 1e-10


def test_heading_and_yaw():
    assert np.isclose(g.heading(g.yaw(0.7)), 0.7)
    assert np.isclose(g.heading(g.multiply(g.yaw(-2.0), g.exp([0.1, 0.2, 0.0]))), -2.0, atol=0.05)


def test_projection_and_jacobian_against_finite_differences(rng):
    intr = Intrinsics.from_fov(45.0, 640, 480)
    pts = rng.normal(size=(20, 3)) + [0, 0, 4]
    jac = projection_jacobian(intr, pts)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        fd = (project(intr, pts + d) - project(intr, pts - d)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, k], fd, rtol=1e-6, atol=1e-6)


def test_intrinsics_match_mujoco_fovy():
    intr = Intrinsics.from_fov(45.0, 640, 480)
    # A point on the top edge of the vertical field of view projects to v = 0.
    z = 3.0
    y = -z * np.tan(np.deg2rad(22.5))
    assert np.isclose(project(intr, np.array([0.0, y, z]))[1], 0.0)
    assert in_image(intr, np.array([320.0, 0.0])) and not in_image(intr, np.array([640.0, 10.0]))
    assert Intrinsics.from_array(intr.as_array()) == intr


@pytest.mark.parametrize("args", [(45, 0, 480), (45, 640, -1), (0, 640, 480), (180, 640, 480)])
def test_bad_intrinsics(args):
    with pytest.raises(CameraError):
        Intrinsics.from_fov(*args)


def test_finite_difference_rates_are_exact_for_constant_motion(rng):
    """A constant rate about a body-fixed axis, ``q_t = q_0 exp(w t)``, gives ``w`` at every sample
    (ends included); a linear trajectory gives its slope; one sample gives zeros."""
    w = rng.normal(size=3)
    q0 = g.normalize(rng.normal(size=4))
    t = np.arange(7) / 30.0
    q = g.multiply(q0, g.exp(t[:, None] * w))
    np.testing.assert_allclose(g.body_angular_velocity(q, 1.0 / 30.0), np.tile(w, (7, 1)), atol=1e-9)
    x = t[:, None] * np.array([1.0, -2.0, 0.5]) + 3.0
    np.testing.assert_allclose(g.finite_difference(x, 1.0 / 30.0), np.tile([1.0, -2.0, 0.5], (7, 1)),
                               atol=1e-9)
    assert np.array_equal(g.body_angular_velocity(q[:1], 0.1), np.zeros((1, 3)))
    assert np.array_equal(g.finite_difference(x[:1], 0.1), np.zeros((1, 3)))


def test_exp_and_log_kernels_against_the_formulas_in_numpy():
    """The compiled ``exp`` and ``log`` against their formulas written in numpy, for rotation vectors near zero
    (the series), of every size up to a half turn, and quaternions with ``w < 0`` (the shorter way round)."""
    rng = np.random.default_rng(11)
    v = rng.normal(size=(400, 3)) * np.concatenate([np.full(100, 1e-10), rng.uniform(0, np.pi, 300)])[:, None] / 2
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    scale = np.where(angle > 1e-8, np.sin(0.5 * angle) / np.where(angle > 1e-8, angle, 1.0), 0.5 - angle**2 / 48.0)
    np.testing.assert_allclose(g.exp(v), np.concatenate([np.cos(0.5 * angle), scale * v], axis=-1), rtol=1e-15,
                               atol=1e-300)
    q = g.normalize(rng.normal(size=(400, 4)))
    p = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(p[:, 1:], axis=-1, keepdims=True)
    want = 2.0 * np.arctan2(s, p[:, :1]) / s * p[:, 1:]
    np.testing.assert_allclose(g.log(q), want, rtol=1e-14)
    assert g.exp(v.reshape(4, 100, 3)).shape == (4, 100, 4) and g.log(q.reshape(2, 200, 4)).shape == (2, 200, 3)


@pytest.mark.parametrize("shape", [(4,), (500, 4), (3, 7, 4), (60, 3)])
def test_normalize_equals_dividing_by_numpys_norm(rng, shape):
    """The compiled ``normalize`` gives exactly numpy's ``q / norm(q)`` (the squares summed in the same order), of
    any leading shape and row length, at scales from 1e-3 to 1e3, and rows of unit norm."""
    q = rng.normal(size=shape) * 10.0 ** rng.uniform(-3, 3, size=shape[:-1] + (1,))
    got = g.normalize(q)
    assert got.shape == q.shape
    np.testing.assert_array_equal(got, q / np.linalg.norm(q, axis=-1, keepdims=True))
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), 1.0, rtol=1e-15)


def test_from_matrix_of_a_stack_equals_one_matrix_at_a_time(rng):
    """The tracks' recovered rotations are converted in one call (``ParticleTracks.predict``): each result is
    exactly that of its matrix alone, also for matrices a little off orthonormal (refined rotations), and the
    quaternion's matrix is the rotation."""
    R = g.to_matrix(_random_quats(rng, 9)) + rng.normal(0, 1e-9, (9, 3, 3))
    stacked = g.from_matrix(R)
    np.testing.assert_array_equal(stacked, np.stack([g.from_matrix(m) for m in R]))
    np.testing.assert_allclose(g.to_matrix(stacked), R, atol=1e-8)
    assert (stacked[:, 0] >= 0).all()
