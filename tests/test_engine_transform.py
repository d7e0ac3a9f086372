"""The database transformation against Monte-Carlo sampling through exact FK, point velocities and projection."""

import numpy as np
import pytest

from harness import geometry
from harness.body import forward_points, forward_points_and_jacobians, point_jacobians, point_velocities, sample_surface
from harness.engine.particle_filter import camera_pitch, upright_orientations
from harness.engine.transform import JointGaussians, PointDistributions, state_point_distributions, to_image
from harness.pinhole import Intrinsics, project


_RATE = np.random.default_rng(11).normal(0.0, 1.0, 50)


def _rel_frobenius(a, b):
    """Relative error per point; points on the root body have no angle-driven covariance (both ~0)."""
    scale = np.linalg.norm(b, axis=(-2, -1))
    err = np.linalg.norm(a - b, axis=(-2, -1))
    return np.where(scale > 1e-12, err / np.maximum(scale, 1e-300), err)


@pytest.fixture(scope="module")
def monte_carlo(body):
    rng = np.random.default_rng(3)
    points = sample_surface(body, 12, rng)
    theta = body.random_angles(rng, scale=0.3)
    theta_std = np.full(50, np.deg2rad(3.0))
    rate = _RATE
    rate_std = np.full(50, 0.3)
    v, v_std = np.array([1.0, 0.1, 0.0]), np.full(3, 0.1)
    w, w_std = np.array([0.1, 0.0, 0.5]), np.full(3, 0.1)
    dist = state_point_distributions(body, JointGaussians(theta, theta_std**2, rate, rate_std**2, v, v_std**2, w,
                                                          w_std**2), points, spread=0.0)
    n = 3000
    thetas = theta + rng.normal(0.0, 1.0, (n, 50)) * theta_std
    qpos = np.zeros((n, 57))
    qpos[:, 3] = 1.0
    qpos[:, 7:] = thetas
    pos = forward_points(body, qpos, points.body, points.local, frame="base")
    vel = point_velocities(body, qpos, rate + rng.normal(0.0, 1.0, (n, 50)) * rate_std,
                           v + rng.normal(0.0, 1.0, (n, 3)) * v_std, w + rng.normal(0.0, 1.0, (n, 3)) * w_std,
                           points.body, points.local)
    return body, points, theta, dist, pos, vel


def _cov(samples):
    d = samples - samples.mean(axis=0)
    return np.einsum("npi,npj->pij", d, d) / (len(samples) - 1)


def test_body_frame_means_and_covariances_match_monte_carlo(monte_carlo):
    body, points, theta, dist, pos, vel = monte_carlo
    qpos = body.qpos(theta, base_pos=np.zeros(3), base_quat=np.array([1.0, 0, 0, 0]))
    exact = forward_points(body, qpos, points.body, points.local, frame="base")
    np.testing.assert_allclose(dist.pos[0], exact, atol=1e-12)
    assert _rel_frobenius(dist.pos_cov[0], _cov(pos)).max() < 0.10
    assert _rel_frobenius(dist.vel_cov[0], _cov(vel)).max() < 0.10
    # The mean velocity is first order too: compare with the sample mean within its standard error.
    se = np.sqrt(np.einsum("pii->pi", _cov(vel)) / len(vel))
    assert np.all(np.abs(dist.vel[0] - vel.mean(axis=0)) < 5 * se + 0.02)


def test_jdot_term_matters(monte_carlo):
    """Dropping the d(J theta_dot)/d(theta) term makes the velocity covariance clearly wrong: the Monte-Carlo
    comparison above is sensitive to it."""
    body, points, theta, dist, pos, vel = monte_carlo
    qpos = body.qpos(theta, base_pos=np.zeros(3), base_quat=np.array([1.0, 0, 0, 0]))
    jac = point_jacobians(body, qpos, points.body, points.local, frame="base")
    theta_var = np.deg2rad(3.0) ** 2
    w = np.array([0.1, 0.0, 0.5])
    skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    h_full = dist.vel_cov[0]
    # Rebuild the covariance with H = [omega]_x J only (no Jdot): subtract the full H term, add the partial.
    partial = skew @ jac
    without = h_full + theta_var * (partial @ np.swapaxes(partial, -1, -2)) - _h_term(body, theta, points, dist)
    with_term = _rel_frobenius(h_full, _cov(vel)).max()
    assert _rel_frobenius(without, _cov(vel)).max() > 1.5 * with_term


def _h_term(body, theta, points, dist):
    """The full ``H S_theta H^T`` term, recovered as vel_cov minus the other (theta-independent) terms."""
    no_theta = state_point_distributions(body, JointGaussians(theta, np.zeros(50), _RATE, np.full(50, 0.09),
                                                              np.array([1.0, 0.1, 0.0]), np.full(3, 0.01),
                                                              np.array([0.1, 0.0, 0.5]), np.full(3, 0.01)), points)
    return dist.vel_cov[0] - no_theta.vel_cov[0]


def test_image_distributions_match_monte_carlo(monte_carlo):
    body, points, theta, dist, pos, vel = monte_carlo
    intr = Intrinsics.from_fov(45.0, 640, 480)
    quat = upright_orientations(np.array([0.7]), camera_pitch(0.2))
    rot = geometry.to_matrix(quat)
    trans = np.array([[0.2, 0.1, 4.0]])
    img = to_image(intr, rot, trans, dist)
    X = pos @ rot[0].T + trans[0]
    Xdot = vel @ rot[0].T
    pix = project(intr, X)
    # Image velocity of each sample: d/dt pi(X) = P(X) Xdot, exactly, per sample.
    from harness.pinhole import projection_jacobian
    flow = np.einsum("npij,npj->npi", projection_jacobian(intr, X), Xdot)
    mean_pix = project(intr, dist.pos[0] @ rot[0].T + trans[0])
    np.testing.assert_allclose(img.pix[0], mean_pix, atol=1e-6)
    assert _rel_frobenius(img.pix_cov[0], _cov(pix)).max() < 0.10
    assert _rel_frobenius(img.flow_cov[0], _cov(flow)).max() < 0.10


@pytest.mark.parametrize("P", [12, 300])          # one chunk of the compiled pass, and three
def test_projection_matches_the_formulas_in_numpy(P):
    """``to_image`` for random states and poses (``state_index``, several chunks of points, a moving camera)
    against the projection written out in numpy: ``u = pi(R x + t)``, the image velocity ``J (R xdot - v_c -
    w_c x X)``, the covariances ``J R S R^T J^T`` with ``J = d pi / dX``, the facing test."""
    from harness.pinhole import projection_jacobian

    rng = np.random.default_rng(7)
    S, H = 3, 5
    A = rng.normal(0, 0.05, (2, S, P, 3, 3))
    normal = rng.normal(size=(S, P, 3))
    dist = PointDistributions(rng.normal(0, 0.5, (S, P, 3)), A[0] @ np.swapaxes(A[0], -1, -2),
                              rng.normal(0, 1.0, (S, P, 3)), A[1] @ np.swapaxes(A[1], -1, -2),
                              normal / np.linalg.norm(normal, axis=-1, keepdims=True), np.zeros((S, 3)),
                              np.zeros((S, 3)))
    intr = Intrinsics.from_fov(45.0, 640, 480)
    rot = geometry.to_matrix(geometry.normalize(rng.normal(size=(H, 4))))
    trans = np.column_stack([rng.normal(0, 0.3, (H, 2)), rng.uniform(3.0, 5.0, H)])
    ego = np.array([0.3, -0.1, 0.2, 0.05, -0.02, 0.1])
    state_index = rng.integers(0, S, H)
    img = to_image(intr, rot, trans, dist, camera_motion=ego, state_index=state_index)
    for h in range(H):
        s, R = state_index[h], rot[h]
        X = dist.pos[s] @ R.T + trans[h]
        J = projection_jacobian(intr, X)
        np.testing.assert_allclose(img.pix[h], project(intr, X), rtol=1e-12)
        Xdot = dist.vel[s] @ R.T - ego[:3] - np.cross(ego[3:], X)
        np.testing.assert_allclose(img.flow[h], np.einsum("pij,pj->pi", J, Xdot), rtol=1e-10, atol=1e-9)
        JR = J @ R
        for got, cov in ((img.pix_cov[h], dist.pos_cov[s]), (img.flow_cov[h], dist.vel_cov[s])):
            np.testing.assert_allclose(got, JR @ cov @ np.swapaxes(JR, -1, -2), rtol=1e-10, atol=1e-9)
        facing = np.einsum("pi,pi->p", dist.normal[s] @ R.T, X) < 0
        np.testing.assert_array_equal(img.visibility[h], facing.astype(float))


def test_moving_camera_changes_flow_by_ego_motion(monte_carlo):
    body, points, theta, dist, pos, vel = monte_carlo
    intr = Intrinsics.from_fov(45.0, 640, 480)
    rot = geometry.to_matrix(upright_orientations(np.array([0.0]), camera_pitch(0.0)))
    trans = np.array([[0.0, 0.0, 4.0]])
    still = to_image(intr, rot, trans, dist)
    # A camera translating along its own x axis at 1 m/s makes a point straight ahead drift by -fx/Z px/s.
    moving = to_image(intr, rot, trans, dist, camera_motion=np.array([1.0, 0, 0, 0, 0, 0]))
    X = dist.pos[0] @ rot[0].T + trans[0]
    np.testing.assert_allclose(moving.flow[0, :, 0] - still.flow[0, :, 0], -intr.fx / X[:, 2], rtol=1e-9)


def _skew(v):
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def _carried_in_numpy(body, g, points, spread):
    """The body-frame transform of the module docstring written out in numpy (the implementation before the
    compiled one): FK and Jacobians of every state at once, Jdot by differences, the normals as differences of
    positions, the covariances as matrix products."""
    angles = np.atleast_2d(g.angles)
    S = len(angles)
    qpos = np.zeros((S, 57))
    qpos[:, 3] = 1.0
    qpos[:, 7:] = angles
    pos, jac = forward_points_and_jacobians(body, qpos, points.body, points.local, frame="base")
    rates = np.atleast_2d(g.rates)
    step = 1e-4 / np.maximum(np.abs(rates).max(axis=1, keepdims=True), 1e-12)
    hi, lo = qpos.copy(), qpos.copy()
    hi[:, 7:] += step * rates
    lo[:, 7:] -= step * rates
    jdot = (forward_points_and_jacobians(body, hi, points.body, points.local, frame="base")[1]
            - forward_points_and_jacobians(body, lo, points.body, points.local, frame="base")[1]) / (2 * step[:, :, None, None])
    normal = forward_points(body, qpos, points.body, points.local + points.normal, frame="base") - pos
    w, v = np.atleast_2d(g.base_angular), np.atleast_2d(g.base_linear)
    vel = np.einsum("spij,sj->spi", jac, rates) + v[:, None] + np.cross(w[:, None], pos)
    h = jdot + _skew(w)[:, None] @ jac
    theta_var = np.atleast_2d(g.angle_var)[:, None, None, :]
    pos_cov = (jac * theta_var) @ np.swapaxes(jac, -1, -2) + spread**2 * np.eye(3)
    skew_x = _skew(pos)
    vel_cov = ((h * theta_var) @ np.swapaxes(h, -1, -2)
               + (jac * np.atleast_2d(g.rate_var)[:, None, None, :]) @ np.swapaxes(jac, -1, -2)
               + np.atleast_2d(g.base_linear_var)[:, None, None, :] * np.eye(3)
               + (skew_x * np.atleast_2d(g.base_angular_var)[:, None, None, :]) @ np.swapaxes(skew_x, -1, -2))
    return PointDistributions(pos, pos_cov, vel, vel_cov, normal, v, w)


@pytest.mark.parametrize("case", ["states", "one configuration"])
def test_compiled_transform_equals_the_numpy_one(body, rng, case):
    """``state_point_distributions`` (one compiled pass per state) against the same equations in numpy: several
    states with angle variance (one of them without), and one configuration without angle variance (what
    recovery asks for)."""
    points = sample_surface(body, 40, rng)
    if case == "states":
        S = 5
        angle_var = rng.uniform(0, 0.01, (S, 50))
        angle_var[2] = 0.0
        g = JointGaussians(body.random_angles(rng, S), angle_var, rng.normal(0, 1, (S, 50)), rng.uniform(0, 0.1, (S, 50)),
                           rng.normal(0, 1, (S, 3)), rng.uniform(0, 0.01, (S, 3)), rng.normal(0, 1, (S, 3)),
                           rng.uniform(0, 0.01, (S, 3)))
    else:
        g = JointGaussians.at(body.random_angles(rng), rng.normal(0, 1, 50), rng.uniform(0, 0.1, 50),
                              rng.normal(0, 1, 3), rng.normal(0, 1, 3))
    got, ref = state_point_distributions(body, g, points, 0.02), _carried_in_numpy(body, g, points, 0.02)
    for field in PointDistributions.__dataclass_fields__:
        a, b = getattr(got, field), getattr(ref, field)
        assert a.shape == b.shape, field
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * np.abs(b).max(), err_msg=field)


def test_batched_mixtures_equal_each_mixture_moment_matched_directly(rng):
    """``PointDistributions.mixtures`` (weighted sums of second moments about the states' average, zeros
    skipped) against the moment-matched mixture written out: mean, E[(x - m)(x - m)^T] as the within-state
    covariance plus the spread of the means, the normal's mean direction and the base velocity."""
    S, P = 12, 5
    A = rng.normal(0, 0.1, (S, P, 3, 3))
    B = rng.normal(0, 0.3, (S, P, 3, 3))
    normal = rng.normal(0, 1, (S, P, 3))
    dists = PointDistributions(rng.normal(0, 1, (S, P, 3)) + 2.0, A @ np.swapaxes(A, -1, -2), rng.normal(0, 2, (S, P, 3)),
                               B @ np.swapaxes(B, -1, -2), normal / np.linalg.norm(normal, axis=-1, keepdims=True),
                               rng.normal(0, 1, (S, 3)), rng.normal(0, 1, (S, 3)))
    weights = rng.random((4, S)) * (rng.random((4, S)) < 0.5)
    weights[:, 0] += 0.1                                    # every row has a state
    got = dists.mixtures(weights)
    for j, w in enumerate(weights / weights.sum(axis=1, keepdims=True)):
        for mean, cov, g_mean, g_cov in ((dists.pos, dists.pos_cov, got.pos, got.pos_cov),
                                         (dists.vel, dists.vel_cov, got.vel, got.vel_cov)):
            m = np.einsum("s,spi->pi", w, mean)
            d = mean - m
            c = np.einsum("s,spij->pij", w, cov) + np.einsum("s,spi,spj->pij", w, d, d)
            np.testing.assert_allclose(g_mean[j], m, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(g_cov[j], c, rtol=1e-10, atol=1e-12)
        n = np.einsum("s,spi->pi", w, dists.normal)
        np.testing.assert_allclose(got.normal[j], n / np.linalg.norm(n, axis=-1, keepdims=True), rtol=1e-12)
        np.testing.assert_allclose(got.base_linear[j], w @ dists.base_linear, rtol=1e-12)
        np.testing.assert_allclose(got.base_angular[j], w @ dists.base_angular, rtol=1e-12)
    one = dists.mixture(weights[1])
    np.testing.assert_allclose(one.pos_cov[0], got.pos_cov[1], rtol=1e-12)
