"""Recovery: joint angles from the recognised primitive's state belief, refined to the observed 2D points.

The prior is the belief-weighted mixture of the recognised HMM's states, moment-matched to one Gaussian
``N(theta_0, diag(s^2))``; the base pose prior is the particle filter's estimate with the cloud's spread.
Refinement is a few damped Gauss-Newton steps on

    sum_p W_p |u_bar_p - pi(R x_p(theta) + t)|^2 + |(theta - theta_0)/s|^2 + pose prior terms

where the soft assignment of flows to model points (the responsibilities, held fixed during the steps, as in
EM) gives each model point the weight ``W_p = sum_m r_mp / sigma_p^2`` and the target ``u_bar_p``, the
responsibility-weighted mean of the flows it explains. Aggregating per point makes a step cost one FK and
Jacobian evaluation of the model points, whatever the number of flows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from harness import geometry
from harness.body.model import BodyModel
from harness.body.surface import SurfacePoints
from harness.body.tree import body_frames_into, frame_work, points_and_jacobians_into
from harness.engine.bottom_up import fuse
from harness.engine.config import RecoverySettings
from harness.engine.features import ANGLE_RATES, ANGLES
from harness.engine.likelihood import FlowModel, responsibilities
from harness.engine.transform import MIN_DEPTH, JointGaussians, state_point_distributions, to_image
from harness.pinhole import Intrinsics

if TYPE_CHECKING:
    from harness.engine.frame import Frame
    from harness.engine.scoring import Scorer


@dataclass(frozen=True)
class Recovery:
    """A configuration recovery produced: angles ``(50,)``, base position ``(3,)`` and rotation ``(3, 3)`` in
    the camera frame. refined: whether recovery worked on it this frame (the track was among the
    ``recover_tracks`` with the most evidence), so that its next proposal may be guided by it; else it is the
    belief's mean angles at the filter's estimate."""

    angles: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    refined: bool = True

    @property
    def qpos(self) -> np.ndarray:
        """``(57,)``: base position, base quaternion (camera from base, w >= 0), angles."""
        out = np.empty(57)
        out[:3] = self.position
        _quaternion(np.ascontiguousarray(self.rotation, dtype=float), out[3:7])
        out[7:] = self.angles
        return out


@dataclass(frozen=True)
class Prior:
    """Recovery's Gaussian prior: angles ``(50,)`` with std ``(50,)`` (rad), the base position ``(3,)`` with
    std ``(3,)`` (m) and the base rotation ``(3, 3)`` with an isotropic std (rad), camera frame."""

    angles: np.ndarray
    angle_std: np.ndarray
    position: np.ndarray
    position_std: np.ndarray
    rotation: np.ndarray
    rotation_std: float


def refine_pose(body: BodyModel, points: SurfacePoints, intr: Intrinsics, flows: np.ndarray, resp: np.ndarray,
                prior: Prior, *, noise_px: float, spread: float, iterations: int = 3, damping: float = 1e-3,
                start: Recovery | None = None, fix_pose: bool = False) -> Recovery:
    """Refine angles ``(50,)`` and the base pose (camera frame) to the observed flow positions.

    ``fix_pose``: the base pose is given (the ground-truth-pose baseline) and only the angles move.

    ``resp`` ``(M, P)``: soft assignment of the ``M`` flows to the ``P`` model points. The steps start from
    ``start`` when given, else from the prior's means. Returns the refined configuration; with no flows, the
    start.
    """
    if start is None:
        start = Recovery(prior.angles, prior.position, prior.rotation)
    angles = np.clip(np.asarray(start.angles, dtype=float), body.lower, body.upper)
    pos = np.array(start.position, dtype=float)
    rot = np.array(start.rotation, dtype=float)
    flows = np.asarray(flows, dtype=float).reshape(-1, 4)
    mass = resp.sum(axis=0)                                          # (P,)
    used = np.flatnonzero(mass > 1e-3)
    used = used[np.argsort(points.body[used], kind="stable")]       # grouped by body (``_normal_equations``)
    if len(flows) == 0 or not len(used) or iterations <= 0:
        return Recovery(angles, pos, rot)
    target = (resp[:, used].T @ flows[:, :2]) / mass[used, None]      # (P_used, 2)
    prior_prec = np.concatenate([1.0 / np.asarray(prior.angle_std) ** 2, 1.0 / np.asarray(prior.position_std) ** 2,
                                 np.full(3, 1.0 / prior.rotation_std**2)])
    _gauss_newton(body.tree.arrays, points.body[used], points.local[used], target, mass[used],
                  np.array([intr.fx, intr.fy, intr.cx, intr.cy]), float(noise_px), float(spread),
                  np.asarray(prior.angles, dtype=float), np.asarray(prior.position, dtype=float),
                  np.asarray(prior.rotation, dtype=float), prior_prec, body.lower, body.upper, int(iterations),
                  float(damping), bool(fix_pose), angles, pos, rot)
    return Recovery(angles, pos, rot)


@numba.njit(cache=True)
def _gauss_newton(tree, point_body, point_local, target, mass, camera, noise_px, spread, prior_angles, prior_pos,
                  prior_rot, prior_prec, lower, upper, iterations, damping, fix_pose, angles, pos, rot):
    """The steps of ``refine_pose`` on ``angles``, ``pos``, ``rot`` in place: each solves
    ``(A + Lambda) (1 + damping) step = b - Lambda offset`` (``_normal_equations``; ``Lambda`` the prior's
    precisions, ``offset`` the distance from the prior's means, the rotation's as a rotation vector), then
    moves the angles (within their limits), the position, and the rotation by the step's rotation vector in
    the base frame. Stops early when a point comes nearer the camera than ``MIN_DEPTH``."""
    Q, J = len(point_body), len(angles)
    n = J + 6
    frames = frame_work(tree)
    eye, zero = np.eye(3), np.zeros(3)
    x, jac = np.empty((Q, 3)), np.empty((Q, 3, J))
    A, b, offset, turn = np.empty((n, n)), np.empty(n), np.empty(n), np.empty((3, 3))
    for _ in range(iterations):
        body_frames_into(tree, angles, eye, zero, frames)
        points_and_jacobians_into(tree, frames, point_body, point_local, x, jac)
        if not _normal_equations(tree, point_body, x, jac, target, mass, camera, noise_px, spread, pos, rot, A, b):
            break
        for k in range(J):
            offset[k] = angles[k] - prior_angles[k]
        for a in range(3):
            offset[J + a] = pos[a] - prior_pos[a]
        _rotation_vector(prior_rot.T @ rot, offset[J + 3:])
        for k in range(n):
            A[k, k] = (A[k, k] + prior_prec[k]) * (1.0 + damping)
            b[k] -= prior_prec[k] * offset[k]
        m = J if fix_pose else n
        step = np.linalg.solve(A[:m, :m], b[:m])
        for k in range(J):
            angles[k] = min(max(angles[k] + step[k], lower[k]), upper[k])
        if not fix_pose:
            for a in range(3):
                pos[a] += step[J + a]
            _rotation_matrix(step[J + 3:], turn)
            rot[:] = rot @ turn


@numba.njit(cache=True)
def _normal_equations(tree, point_body, x, jac, target, mass, camera, noise_px, spread, pos, rot, A, b):
    """``A = sum_p W_p G_p^T G_p`` ``(56, 56)`` and ``b = sum_p W_p G_p^T (u_bar_p - u_p)`` of the projections
    ``u_p = pi(R x_p + t)`` of the points ``x`` ``(Q, 3)`` (base frame, grouped by body) with Jacobians ``jac``,
    linearised as

        G_p = [P_p R J_p | P_p | -P_p R [x_p]_x]        (2 x 56: angles, position, rotation in the base frame)

    with ``P_p = d pi / dX`` and ``W_p = mass_p / (noise^2 + (f_y spread / Z_p)^2)``. A point moves only its
    chain's hinges and the pose: the points of one body are summed in a dense block of those columns, added to
    ``A`` once per body. Returns False (and leaves ``A``, ``b``) when a point is nearer the camera than
    ``MIN_DEPTH``."""
    Q, J = jac.shape[0], jac.shape[2]
    chain, chain_len = tree[7], tree[8]
    X = np.empty((Q, 3))
    for i in range(Q):
        for a in range(3):
            X[i, a] = pos[a] + rot[a, 0] * x[i, 0] + rot[a, 1] * x[i, 1] + rot[a, 2] * x[i, 2]
        if X[i, 2] < MIN_DEPTH:
            return False
    A[:] = 0.0
    b[:] = 0.0
    column, g, PR = np.empty(J + 6, dtype=np.int64), np.empty(J + 6), np.empty((2, 3))
    block, block_b = np.empty((J + 6, J + 6)), np.empty(J + 6)
    first = 0
    while first < Q:
        body = point_body[first]
        last = first
        while last < Q and point_body[last] == body:
            last += 1
        L = chain_len[body]
        n = L + 6
        for c in range(L):
            column[c] = chain[body, c]
        for c in range(6):
            column[L + c] = J + c
        block[:n, :n] = 0.0
        block_b[:n] = 0.0
        for i in range(first, last):
            _add_point(X[i], x[i], jac[i], target[i], mass[i], camera, noise_px, spread, rot, column[:L], g[:n], PR,
                       block, block_b)
        for c in range(n):
            b[column[c]] += block_b[c]
            for d in range(c, n):
                A[column[c], column[d]] += block[c, d]
        first = last
    for k in range(J + 6):              # a chain's hinges are in model order: the upper triangle is filled
        for q in range(k):
            A[k, q] = A[q, k]
    return True


@numba.njit(cache=True)
def _add_point(X, x, jac, target, mass, camera, noise_px, spread, rot, chain, g, PR, block, block_b):
    """Add one point's ``W G^T G`` and ``W G^T (u_bar - u)`` to its body's dense block of columns (its chain's
    hinges ``chain``, then the pose's six); ``X``: the point in the camera frame, ``x`` in the base frame, ``jac``
    its Jacobian ``(3, J)``; ``g``, ``PR``: work arrays."""
    fx, fy, cx, cy = camera[0], camera[1], camera[2], camera[3]
    L, n = len(chain), len(g)
    iz = 1.0 / X[2]
    w = mass / (noise_px**2 + (fy * spread / X[2]) ** 2)
    # P = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]]; P R row by row.
    pu0, pu2 = fx * iz, -fx * X[0] * iz * iz
    pv1, pv2 = fy * iz, -fy * X[1] * iz * iz
    for c in range(3):
        PR[0, c] = pu0 * rot[0, c] + pu2 * rot[2, c]
        PR[1, c] = pv1 * rot[1, c] + pv2 * rot[2, c]
    residual = (target[0] - (fx * X[0] * iz + cx), target[1] - (fy * X[1] * iz + cy))
    for row in range(2):
        p0, p1, p2 = PR[row, 0], PR[row, 1], PR[row, 2]
        for c in range(L):
            k = chain[c]
            g[c] = p0 * jac[0, k] + p1 * jac[1, k] + p2 * jac[2, k]
        g[L], g[L + 1], g[L + 2] = (pu0, 0.0, pu2) if row == 0 else (0.0, pv1, pv2)
        # -P R [x]_x, column by column: -(P R) (e_c x x).
        g[L + 3] = -(p1 * x[2] - p2 * x[1])
        g[L + 4] = -(p2 * x[0] - p0 * x[2])
        g[L + 5] = -(p0 * x[1] - p1 * x[0])
        for c in range(n):
            wg = w * g[c]
            block_b[c] += wg * residual[row]
            for d in range(c, n):
                block[c, d] += wg * g[d]


@numba.njit(cache=True)
def _rotation_vector(m, out):
    """The rotation vector (angle in [0, pi]) of a rotation matrix ``m``: its quaternion (``_quaternion``), then
    ``geometry.log``."""
    q = np.empty(4)
    _quaternion(m, q)
    w, x, y, z = q[0], q[1], q[2], q[3]
    s = np.sqrt(x * x + y * y + z * z)
    scale = 2.0 * np.arctan2(s, w) / s if s > 1e-12 else 2.0 / max(w, 1e-300)
    out[0], out[1], out[2] = scale * x, scale * y, scale * z


@numba.njit(cache=True)
def _quaternion(m, out):
    """The unit quaternion ``(w, x, y, z)``, ``w >= 0``, of a rotation matrix ``m`` by Shepperd's method (the
    largest of ``|w|, |x|, |y|, |z|`` first, so that no division is by a small number): ``geometry.from_matrix``
    without its 4 x 4 eigenproblem."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace >= max(m[0, 0], m[1, 1], m[2, 2]):
        w = 0.5 * np.sqrt(1.0 + trace)
        x, y, z = (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)
    elif m[0, 0] >= max(m[1, 1], m[2, 2]):
        x = 0.5 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        w, y, z = (m[2, 1] - m[1, 2]) / (4 * x), (m[0, 1] + m[1, 0]) / (4 * x), (m[0, 2] + m[2, 0]) / (4 * x)
    elif m[1, 1] >= m[2, 2]:
        y = 0.5 * np.sqrt(1.0 - m[0, 0] + m[1, 1] - m[2, 2])
        w, x, z = (m[0, 2] - m[2, 0]) / (4 * y), (m[0, 1] + m[1, 0]) / (4 * y), (m[1, 2] + m[2, 1]) / (4 * y)
    else:
        z = 0.5 * np.sqrt(1.0 - m[0, 0] - m[1, 1] + m[2, 2])
        w, x, y = (m[1, 0] - m[0, 1]) / (4 * z), (m[0, 2] + m[2, 0]) / (4 * z), (m[1, 2] + m[2, 1]) / (4 * z)
    scale = (-1.0 if w < 0.0 else 1.0) / np.sqrt(w * w + x * x + y * y + z * z)    # unit, as an eigenvector is
    out[0], out[1], out[2], out[3] = scale * w, scale * x, scale * y, scale * z


@numba.njit(cache=True)
def _rotation_matrix(v, out):
    """The rotation matrix of a rotation vector ``v`` (``geometry.exp``, then ``geometry.to_matrix``)."""
    angle = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    half = 0.5 * angle
    scale = np.sin(half) / angle if angle > 1e-8 else 0.5 - angle**2 / 48.0
    w, x, y, z = np.cos(half), scale * v[0], scale * v[1], scale * v[2]
    out[0, 0], out[0, 1], out[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    out[1, 0], out[1, 1], out[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    out[2, 0], out[2, 1], out[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


def mean_angles(model, best: np.ndarray, state_beliefs: np.ndarray) -> np.ndarray:
    """``(J, 50)``: the mean angles of state beliefs ``(J, K)`` over the states of primitives ``best`` ``(J,)``
    (``Track.best_states``): ``recover``'s prior mean, for many tracks in one product."""
    gamma = state_beliefs / state_beliefs.sum(axis=1, keepdims=True)
    means = model.db_means[:, ANGLES].reshape(model.n_classes, model.n_states, -1)[best]
    return np.einsum("jk,jkd->jd", gamma, means)


def recover(scorer: "Scorer", frame: "Frame", state_belief: np.ndarray, position: np.ndarray, rot: np.ndarray,
            position_std: np.ndarray, *, settings: RecoverySettings, refine: bool = True,
            fix_pose: bool = False, posture: tuple[np.ndarray, np.ndarray] | None = None,
            posture_weight: float = 0.0) -> Recovery:
    """Angles of a recognised primitive and a refined pose, by EM against the frame's flows.

    ``state_belief`` ``(S,)`` over all database states (zero outside the recognised primitive). The prior is
    the belief's moment-matched Gaussian over the angles; the pose prior is ``position`` ``(3,)``,
    ``rot`` ``(3, 3)`` with ``position_std`` ``(3,)`` and the setting ``rotation_std`` (``settings``, the
    engine's recovery section, also gives the iterations). The E-step
    assigns flows to model points softly, first under the state belief, then at the current estimate (whose
    points only spread over their surface patch), with the likelihood's visibility and weights; the M-step is
    ``refine_pose``. Without flows, or with ``refine`` false, the prior mean at the given pose.

    ``posture``: a posture independent of this pose (the bottom-up estimate's features ``(106,)`` and their std
    ``(106,)``, ``bottom_up.PostureEstimate.posture_near``), fused with the belief's angles and rates
    (``fuse``, its precision times ``posture_weight``) into the prior, when given.
    """
    model = scorer.model
    idx = np.flatnonzero(state_belief > 0)
    gamma = state_belief[idx] / state_belief[idx].sum()
    angle_means = model.db_means[idx, ANGLES]
    theta0 = gamma @ angle_means
    current = Recovery(theta0, position, rot, refined=refine)
    if not refine or not frame.has_flows:      # every track, every frame: only the mean angles
        return current
    rate_means, covars = model.db_means[idx, ANGLE_RATES], model.db_covars[idx]
    var = gamma @ (covars[:, ANGLES] + (angle_means - theta0) ** 2)
    rates = gamma @ rate_means
    rate_var = gamma @ (covars[:, ANGLE_RATES] + (rate_means - rates) ** 2)
    if posture is not None and posture_weight > 0:
        feats, feats_std = posture
        theta0, var = fuse(theta0, var, feats[ANGLES], feats_std[ANGLES] ** 2, posture_weight)
        rates, rate_var = fuse(rates, rate_var, feats[ANGLE_RATES], feats_std[ANGLE_RATES] ** 2, posture_weight)
        current = Recovery(theta0, position, rot, refined=refine)
    prior = Prior(theta0, np.sqrt(var), position, position_std, rot, settings.rotation_std)
    mix = model.dists.mixture(state_belief)
    for it in range(settings.em_iterations):
        if it:
            mix = state_point_distributions(model.body, JointGaussians.at(current.angles, rates, rate_var,
                                                                          mix.base_linear[0], mix.base_angular[0]),
                                            model.points, model.spread)
        img = scorer.image(frame, current.rotation[None], current.position[None], mix)
        resp = scorer.responsibilities(frame, img)
        current = refine_pose(model.body, model.points, frame.intr, frame.flows, resp, prior,
                              noise_px=scorer.settings.noise_px, spread=model.spread,
                              iterations=settings.refine_iterations, start=current, fix_pose=fix_pose)
    return current


def fit_without_database(body: BodyModel, points: SurfacePoints, intr: Intrinsics, flows: list[np.ndarray],
                         base_pos: np.ndarray, base_quat: np.ndarray, *, noise_px: float, spread: float,
                         angle_step_std: float = 0.3, iterations: int = 2) -> np.ndarray:
    """The no-database ablation: per frame, fit the 50 angles to the flow positions alone (soft assignment to
    the model points at the current angles, Gauss-Newton), from the previous frame's angles with a weak
    smoothness prior of ``angle_step_std`` rad, at a given base pose ``(T, 3)``, ``(T, 4)``. Returns
    ``(T, 50)`` angles. No HMM, no recognition: what the database's prior adds is the difference."""
    angles = np.zeros(50)
    out = np.empty((len(flows), 50))
    # Positions only: a velocity variance this wide makes the inlier's velocity factor constant, 1 / (2 pi var),
    # and the outlier term's uniform velocity disc of radius sqrt(2 var) has the same density, so the factor
    # cancels from the responsibilities. (With the outlier's usual disc it would outweigh every inlier.)
    velocity_var = 1e12
    flow_model = FlowModel(noise_px, 1.0, intr.width, intr.height, max_flow=np.sqrt(2.0 * velocity_var))
    for t, f in enumerate(flows):
        rot = geometry.to_matrix(base_quat[t])
        for _ in range(iterations if len(f) else 0):
            dist = state_point_distributions(body, JointGaussians.at(angles), points, spread)
            img = to_image(intr, rot[None], base_pos[t][None], dist)
            img = type(img)(img.pix, img.pix_cov, img.flow,
                            np.broadcast_to(velocity_var * np.eye(2), img.flow_cov.shape), img.visibility)
            resp = responsibilities(f, img, flow_model)
            prior = Prior(angles, np.full(50, angle_step_std), base_pos[t], np.full(3, 1e-4), rot, 1e-4)
            angles = refine_pose(body, points, intr, f, resp, prior, noise_px=noise_px, spread=spread,
                                 iterations=1).angles
        out[t] = angles
    return out
