"""The database in the image: each HMM state's output distribution carried to model points, then to pixels.

Body frame (once per database). For state ``(c, k)`` with angle mean/variance ``theta, S_theta``, rate
mean/variance ``theta_dot, S_rate`` and base velocity ``v, S_v``, ``omega, S_omega`` (all base frame), a
body-fixed model point ``p`` has, to first order about the means,

    position  x = FK_p(theta),                         cov  J S_theta J^T + s_patch^2 I
    velocity  xdot = J theta_dot + v + omega x x,       cov  H S_theta H^T + J S_rate J^T + S_v
                                                             + [x]_x S_omega [x]_x^T

with ``J = dFK_p/dtheta`` and ``H = d(xdot)/dtheta = Jdot + [omega]_x J``. ``Jdot`` (the derivative of the
Jacobian along ``theta_dot``) equals ``d(J theta_dot)/dtheta`` because mixed second derivatives of the point
position commute; it is taken by a central difference of ``J`` along ``theta_dot``. ``s_patch`` is the spread
of the surface patch a model point stands for: the markers are not at the model points.

Image (per pose hypothesis). With the base pose ``(R, t)`` in the camera frame: ``X = R x + t``,
``Xdot = R xdot`` (minus the camera's own motion ``v_c + omega_c x X`` when it moves), and the pinhole
Jacobian ``P = d(u, v)/dX`` maps both covariances: ``P R S R^T P^T``; ``udot = P Xdot``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from harness.body.model import BodyModel
from harness.body.surface import SurfacePoints, geom_area
from harness.body.tree import body_frames_into, frame_work, points_and_jacobians_into
from harness.engine.database import MotionDatabase
from harness.engine.features import ANGLE_RATES, ANGLES, BASE_ANGULAR, BASE_LINEAR
from harness.pinhole import Intrinsics

_JDOT_STEP = 1e-4          # radians moved along theta_dot for the central difference of J
MIN_DEPTH = 0.05           # metres: points nearer the camera than this are treated as not visible


@dataclass(frozen=True)
class PointDistributions:
    """Gaussian position and velocity of ``P`` model points in the base frame, for ``S`` states.

    pos, vel: ``(S, P, 3)`` (m, m/s); pos_cov, vel_cov: ``(S, P, 3, 3)``; normal: ``(S, P, 3)`` unit
    outward normals; base_linear, base_angular: ``(S, 3)`` the states' base velocity means (base frame).
    """

    pos: np.ndarray
    pos_cov: np.ndarray
    vel: np.ndarray
    vel_cov: np.ndarray
    normal: np.ndarray
    base_linear: np.ndarray
    base_angular: np.ndarray

    def take(self, index) -> "PointDistributions":
        return PointDistributions(*(getattr(self, f)[index] for f in self.__dataclass_fields__))

    @staticmethod
    def concatenate(parts: list["PointDistributions"]) -> "PointDistributions":
        """The states of several distributions, in order."""
        return PointDistributions(*(np.concatenate([getattr(p, f) for p in parts])
                                    for f in PointDistributions.__dataclass_fields__))

    def mixture(self, weights: np.ndarray) -> "PointDistributions":
        """The moment-matched single Gaussian of the states' mixture with ``weights`` (S,): one 'state'."""
        return self.mixtures(np.asarray(weights, dtype=float)[None])

    def mixtures(self, weights: np.ndarray) -> "PointDistributions":
        """``n`` moment-matched Gaussians of the states' mixtures with ``weights`` ``(n, S)`` (each row
        normalised here; zeros are skipped), in one pass: the weighted sums of ``_moments``' rows. The moments
        are taken about the states' average (so that ``E[x x^T] - m m^T`` loses no digits); the normals are the
        weighted mean direction."""
        w = np.ascontiguousarray(weights, dtype=float)
        w = w / w.sum(axis=1, keepdims=True)
        centre, table = self._moments
        return PointDistributions(*_moment_matched(_weighted_rows(table, w), centre))

    @cached_property
    def _moments(self) -> tuple[np.ndarray, np.ndarray]:
        """The states' average position and velocity per point ``(2, P, 3)``, and per state one row ``(S, X)``:
        positions and velocities about that average, their second moments ``S + d d^T``, the normals and the
        base velocities (computed once per distribution set; read-only)."""
        centre = np.stack([self.pos.mean(axis=0), self.vel.mean(axis=0)])
        dp, dv = self.pos - centre[0], self.vel - centre[1]
        S = len(dp)
        table = np.concatenate([dp.reshape(S, -1), (self.pos_cov + dp[..., :, None] * dp[..., None, :]).reshape(S, -1),
                                dv.reshape(S, -1), (self.vel_cov + dv[..., :, None] * dv[..., None, :]).reshape(S, -1),
                                self.normal.reshape(S, -1), self.base_linear, self.base_angular], axis=1)
        return centre, np.ascontiguousarray(table)

    @cached_property
    def rows(self) -> np.ndarray:
        """The states' points laid out for the projection, ``(S, chunks, _STATE_ROWS * _CHUNK)``
        (``_state_rows``; computed once per distribution set, read-only)."""
        return _state_rows(self.pos, self.pos_cov, self.vel, self.vel_cov, self.normal)


@numba.njit(cache=True, fastmath={"reassoc", "contract", "nsz"})
def _weighted_rows(table, weights):
    """``(n, X)``: ``weights (n, S) @ table (S, X)``, skipping zero weights (a track's belief covers the states
    of one or a few primitives: a dense product would cost ten times more). State by state, so that each row of
    the table (32 KB at 150 points) is read once for all the mixtures that weigh it; each sum still runs over
    the states in order."""
    n, S = weights.shape
    X = table.shape[1]
    out = np.zeros((n, X))
    for s in range(S):
        source = table[s]
        for j in range(n):
            w = weights[j, s]
            if w != 0.0:
                row = out[j]
                for x in range(X):
                    row[x] += w * source[x]
    return out


@numba.njit(cache=True)
def _moment_matched(sums, centre):
    """The moment-matched Gaussians of ``_weighted_rows``' sums ``(n, X)`` of ``_moments``' rows, about the
    states' average ``centre`` ``(2, P, 3)``: ``PointDistributions``' fields. Covariances ``E[d d^T] - m m^T``,
    normals the weighted mean direction (without fused multiply-adds, as numpy computes them)."""
    n = sums.shape[0]
    P = centre.shape[1]
    pos, vel, normal = np.empty((n, P, 3)), np.empty((n, P, 3)), np.empty((n, P, 3))
    pos_cov, vel_cov = np.empty((n, P, 3, 3)), np.empty((n, P, 3, 3))
    lin, ang = np.empty((n, 3)), np.empty((n, 3))
    for j in range(n):
        row = sums[j]
        for p in range(P):
            for which in range(2):
                first = 0 if which == 0 else 12 * P
                mean = row[first + 3 * p:first + 3 * p + 3]
                second = row[first + 3 * P + 9 * p:first + 3 * P + 9 * p + 9]
                out = pos if which == 0 else vel
                cov = pos_cov if which == 0 else vel_cov
                for a in range(3):
                    out[j, p, a] = mean[a] + centre[which, p, a]
                    for b in range(3):
                        cov[j, p, a, b] = second[3 * a + b] - mean[a] * mean[b]
            at = 24 * P + 3 * p
            length = np.sqrt(row[at] * row[at] + row[at + 1] * row[at + 1] + row[at + 2] * row[at + 2])
            length = max(length, 1e-12)
            for a in range(3):
                normal[j, p, a] = row[at + a] / length
        for a in range(3):
            lin[j, a] = row[27 * P + a]
            ang[j, a] = row[27 * P + 3 + a]
    return pos, pos_cov, vel, vel_cov, normal, lin, ang


def patch_std(body: BodyModel, n_points: int) -> float:
    """Per-axis spread (m) of a uniform disc of the area each of ``n_points`` model points stands for."""
    m = body.model
    area = sum(geom_area(int(m.geom_type[g]), m.geom_size[g]) for g in body.body_geoms)
    radius = np.sqrt(area / (np.pi * max(n_points, 1)))
    return float(radius / 2.0)


@dataclass(frozen=True)
class JointGaussians:
    """``S`` joint-space Gaussians with diagonal covariances: means and variances of the angles ``(S, 50)``
    (rad), their rates ``(S, 50)`` (rad/s), and the base's linear ``(S, 3)`` (m/s) and angular ``(S, 3)``
    (rad/s) velocity in the base frame."""

    angles: np.ndarray
    angle_var: np.ndarray
    rates: np.ndarray
    rate_var: np.ndarray
    base_linear: np.ndarray
    base_linear_var: np.ndarray
    base_angular: np.ndarray
    base_angular_var: np.ndarray

    @classmethod
    def from_features(cls, mean: np.ndarray, var: np.ndarray) -> "JointGaussians":
        """From feature means and variances ``(S, 106)`` (``features``)."""
        return cls(mean[:, ANGLES], var[:, ANGLES], mean[:, ANGLE_RATES], var[:, ANGLE_RATES],
                   mean[:, BASE_LINEAR], var[:, BASE_LINEAR], mean[:, BASE_ANGULAR], var[:, BASE_ANGULAR])

    @classmethod
    def at(cls, angles: np.ndarray, rates: np.ndarray | None = None, rate_var: np.ndarray | None = None,
           base_linear: np.ndarray | None = None, base_angular: np.ndarray | None = None) -> "JointGaussians":
        """One configuration ``angles`` ``(50,)`` without angle variance: optionally with rates (and their
        variance) and base velocities; what is not given is zero."""
        zeros50, zeros3 = np.zeros(len(angles)), np.zeros(3)
        return cls(angles, zeros50, zeros50 if rates is None else rates, zeros50 if rate_var is None else rate_var,
                   zeros3 if base_linear is None else base_linear, zeros3,
                   zeros3 if base_angular is None else base_angular, zeros3)


def state_point_distributions(body: BodyModel, gaussians: JointGaussians, points: SurfacePoints,
                              spread: float = 0.0) -> PointDistributions:
    """Carry ``S`` joint-space Gaussians to the ``P`` model points in the base frame (see the module
    docstring); ``spread``: the surface patch's std (m). One compiled pass per state (``_carry``)."""
    g = gaussians
    angles = np.atleast_2d(np.asarray(g.angles, dtype=float))
    S = len(angles)
    per_state = [_per_state(a, S) for a in (g.angles, g.angle_var, g.rates, g.rate_var, g.base_linear,
                                            g.base_linear_var, g.base_angular, g.base_angular_var)]
    P = len(points.body)
    out = PointDistributions(np.empty((S, P, 3)), np.empty((S, P, 3, 3)), np.empty((S, P, 3)), np.empty((S, P, 3, 3)),
                             np.empty((S, P, 3)), per_state[4].copy(), per_state[6].copy())
    _carry(body.tree.arrays, *per_state, np.ascontiguousarray(points.body, dtype=np.int64),
           np.ascontiguousarray(points.local, dtype=float), np.ascontiguousarray(points.normal, dtype=float),
           float(spread), out.pos, out.pos_cov, out.vel, out.vel_cov, out.normal)
    return out


def _per_state(a: np.ndarray, S: int) -> np.ndarray:
    """``(S, n)`` contiguous rows of a per-state parameter given as ``(S, n)``, ``(1, n)`` or ``(n,)``."""
    a = np.asarray(a, dtype=float)
    a = a.reshape(1, -1) if a.ndim == 1 else a
    return np.ascontiguousarray(a if len(a) == S else np.repeat(a, S, axis=0))


@numba.njit(cache=True)
def _carry(tree, angles, angle_var, rates, rate_var, base_linear, base_linear_var, base_angular, base_angular_var,
           point_body, point_local, point_normal, spread, pos, pos_cov, vel, vel_cov, normal):
    """The loop of ``state_point_distributions``: per state the body frames, the points with their Jacobians and
    normals, then each point's moments (``_point_moments``), summed over the hinges on its chain (the other
    columns of J are zero). ``Jdot`` only when the state has angle variance: ``H`` enters only through
    ``H S_theta H^T``."""
    S, J = angles.shape
    P = len(point_body)
    chain, chain_len = tree[7], tree[8]
    frames = frame_work(tree)
    eye, zero = np.eye(3), np.zeros(3)
    jac, jdot, lo = np.empty((P, 3, J)), np.empty((P, 3, J)), np.empty((P, 3, J))
    moved, scratch = np.empty(J), np.empty((P, 3))
    H, skew_x = np.empty((3, J)), np.empty((3, 3))
    for s in range(S):
        with_jdot = False
        for k in range(J):
            with_jdot |= angle_var[s, k] > 0.0
        if with_jdot:
            _jdot_into(tree, angles[s], rates[s], point_body, point_local, frames, moved, scratch, jdot, lo)
        body_frames_into(tree, angles[s], eye, zero, frames)
        points_and_jacobians_into(tree, frames, point_body, point_local, pos[s], jac)
        R = frames[0]
        for i in range(P):
            b = point_body[i]
            for r in range(3):
                normal[s, i, r] = R[b, r, 0] * point_normal[i, 0] + R[b, r, 1] * point_normal[i, 1] \
                    + R[b, r, 2] * point_normal[i, 2]
            _point_moments(pos[s, i], jac[i], jdot[i], with_jdot, chain[b, :chain_len[b]], rates[s], angle_var[s],
                           rate_var[s], base_linear[s], base_linear_var[s], base_angular[s], base_angular_var[s],
                           spread, vel[s, i], pos_cov[s, i], vel_cov[s, i], H, skew_x)


@numba.njit(cache=True)
def _jdot_into(tree, angles, rates, point_body, point_local, frames, moved, scratch, jdot, lo):
    """``Jdot = (J(theta + h theta_dot) - J(theta - h theta_dot)) / 2h`` of one state into ``jdot`` ``(P, 3, J)``,
    ``h = _JDOT_STEP / max |theta_dot|`` (``lo``, ``moved``, ``scratch``: work arrays)."""
    h = _JDOT_STEP / max(np.abs(rates).max(), 1e-12)
    eye, zero = np.eye(3), np.zeros(3)
    for sign in (1.0, -1.0):
        for k in range(len(angles)):
            moved[k] = angles[k] + sign * h * rates[k]
        body_frames_into(tree, moved, eye, zero, frames)
        points_and_jacobians_into(tree, frames, point_body, point_local, scratch, jdot if sign > 0 else lo)
    for i in range(jdot.shape[0]):
        for r in range(3):
            for k in range(jdot.shape[2]):
                jdot[i, r, k] = (jdot[i, r, k] - lo[i, r, k]) / (2 * h)


@numba.njit(cache=True)
def _point_moments(x, jac, jdot, with_jdot, chain, rates, angle_var, rate_var, v, v_var, w, w_var, spread, vel,
                   pos_cov, vel_cov, H, skew_x):
    """One point's velocity ``xdot = J theta_dot + v + omega x x`` and its position and velocity covariances
    (the module docstring), over the hinges ``chain`` that move it (``H``, ``skew_x``: work arrays)."""
    cross = (w[1] * x[2] - w[2] * x[1], w[2] * x[0] - w[0] * x[2], w[0] * x[1] - w[1] * x[0])
    for r in range(3):
        acc = v[r] + cross[r]
        for k in chain:
            acc += jac[r, k] * rates[k]
        vel[r] = acc
    for k in chain:                     # H = Jdot + [omega]_x J
        j0, j1, j2 = jac[0, k], jac[1, k], jac[2, k]
        d0, d1, d2 = (jdot[0, k], jdot[1, k], jdot[2, k]) if with_jdot else (0.0, 0.0, 0.0)
        H[0, k] = d0 + w[1] * j2 - w[2] * j1
        H[1, k] = d1 + w[2] * j0 - w[0] * j2
        H[2, k] = d2 + w[0] * j1 - w[1] * j0
    skew_x[0, 0], skew_x[0, 1], skew_x[0, 2] = 0.0, -x[2], x[1]
    skew_x[1, 0], skew_x[1, 1], skew_x[1, 2] = x[2], 0.0, -x[0]
    skew_x[2, 0], skew_x[2, 1], skew_x[2, 2] = -x[1], x[0], 0.0
    for r in range(3):
        for q in range(r, 3):
            # pos: J S_theta J^T + s^2 I; vel: H S_theta H^T + J S_rate J^T + S_v + [x]_x S_omega [x]_x^T.
            pc = spread * spread if r == q else 0.0
            vc = v_var[r] if r == q else 0.0
            for k in chain:
                pc += jac[r, k] * angle_var[k] * jac[q, k]
                vc += H[r, k] * angle_var[k] * H[q, k] + jac[r, k] * rate_var[k] * jac[q, k]
            for k in range(3):
                vc += skew_x[r, k] * w_var[k] * skew_x[q, k]
            pos_cov[r, q] = pos_cov[q, r] = pc
            vel_cov[r, q] = vel_cov[q, r] = vc


def database_point_distributions(db: MotionDatabase, body: BodyModel, points: SurfacePoints,
                                 spread: float | None = None) -> PointDistributions:
    """Every state of every primitive, flattened to ``S = C * K`` in (class, state) order."""
    db.validate()
    C, K, D = db.means_.shape
    mean, var = db.means_.reshape(C * K, D), db.covars_.reshape(C * K, D)
    if spread is None:
        spread = patch_std(body, len(points.body))
    return state_point_distributions(body, JointGaussians.from_features(mean, var), points, spread)


@dataclass(frozen=True)
class ImageDistributions:
    """Per hypothesis ``H`` and model point ``P``: pixel mean ``(H, P, 2)`` and covariance ``(H, P, 2, 2)``,
    image-velocity mean (px/s) and covariance, and the point's visibility ``(H, P)`` in [0, 1]: 0 when it
    faces away from the camera or is behind it, else the soft depth-order test of ``to_image``."""

    pix: np.ndarray
    pix_cov: np.ndarray
    flow: np.ndarray
    flow_cov: np.ndarray
    visibility: np.ndarray


def to_image(intr: Intrinsics, rot: np.ndarray, trans: np.ndarray, dist: PointDistributions, *,
             camera_motion: np.ndarray | None = None, state_index: np.ndarray | None = None,
             occlusion: tuple[float, float] | None = None) -> ImageDistributions:
    """Project body-frame point distributions for ``H`` base poses ``rot (H, 3, 3)``, ``trans (H, 3)``.

    Visibility: a point facing away from the camera (outward normal) or behind it is invisible. With
    ``occlusion = (radius, depth)`` (metres), the body also hides itself: every camera-facing point ``q``
    nearer the camera than point ``p`` by more than ``depth`` covers it with the footprint of the surface
    patch it stands for, ``v_p = prod_q (1 - k(d_pq / (2 r_q)))`` with the compact biweight
    ``k(x) = (1 - x^2)^2`` (``x < 1``; close to a Gaussian of std ``r_q``), ``d_pq`` the pixel distance of
    their means and ``r_q = f_y radius / z_q``. Without it, visibility is the facing test alone.

    Pairing of poses and the ``S`` states of ``dist``: one pose and ``S`` states, ``H`` poses and one state,
    ``H`` poses and ``H`` states (paired), or ``state_index`` ``(H,)``: pose ``h`` with state
    ``state_index[h]`` (every particle of a track with its track's belief, without copying distributions).
    The output has one row per pair. ``camera_motion``: ``(6,)`` camera linear and angular velocity in its
    own frame, or None.
    """
    poses = _projection_arguments(intr, rot, trans, dist, camera_motion=camera_motion, state_index=state_index,
                                 occlusion=occlusion)
    H, P = len(poses[2]), dist.pos.shape[1]
    out = (np.empty((H, P, 2)), np.empty((H, P, 2, 2)), np.empty((H, P, 2)), np.empty((H, P, 2, 2)),
           np.empty((H, P)))
    _project_kernel(*poses, *out)
    return ImageDistributions(*out)


def _projection_arguments(intr: Intrinsics, rot: np.ndarray, trans: np.ndarray, dist: PointDistributions, *,
                         camera_motion: np.ndarray | None, state_index: np.ndarray | None,
                         occlusion: tuple[float, float] | None) -> tuple:
    """What ``_project_kernel`` takes for ``to_image``'s arguments (checked, paired): the poses, each
    hypothesis' pose and state, the body-frame distributions, the camera ``(fx, fy, cx, cy)``, its motion
    ``(6,)`` and the self-occlusion's footprint radius and depth gap (zeros: off)."""
    rot = np.ascontiguousarray(rot, dtype=float).reshape(-1, 3, 3)
    trans = np.ascontiguousarray(trans, dtype=float).reshape(-1, 3)
    ego = np.zeros(6) if camera_motion is None else np.asarray(camera_motion, dtype=float)
    S = dist.pos.shape[0]
    if state_index is None:
        H = max(len(rot), S)
        if len(rot) not in (1, H) or S not in (1, H):
            raise ValueError(f"{S} states for {len(rot)} poses: give one of either, or as many of each")
        state_index = np.zeros(H, dtype=np.int64) if S == 1 else np.arange(H)
        pose_index = np.zeros(H, dtype=np.int64) if len(rot) == 1 else np.arange(H)
    else:
        state_index = np.asarray(state_index, dtype=np.int64)
        H = len(state_index)
        if len(rot) != H or (H and (state_index.min() < 0 or state_index.max() >= S)):
            raise ValueError(f"state_index must give one of {S} states for each of the {len(rot)} poses")
        pose_index = np.arange(H)
    radius, depth = (0.0, 0.0) if occlusion is None else (float(occlusion[0]), float(occlusion[1]))
    return (rot, trans, pose_index, state_index, dist.rows, dist.pos.shape[1],
            np.array([intr.fx, intr.fy, intr.cx, intr.cy]), ego, radius, depth)


# The footprints' product may be taken in any order (it vectorises); nothing assumes away NaN or infinity.
_PRODUCTS = {"reassoc", "contract", "nsz"}
# Visible points up to which self-occlusion runs over all pairs: measured per hypothesis against the grid at 150,
# 300 and 600 model points (about 75, 150 and 300 visible), 2.1x and 1.5x faster, and even.
_ALL_PAIRS = 256


@numba.njit(cache=True)
def _project_kernel(rot, trans, pose_index, state_index, states, P, camera, ego, occ_radius, occ_depth, pix, pix_cov,
                    flow, flow_cov, visibility):
    """The loop of ``to_image``: each hypothesis projected (``_project_pose``, ``_CHUNK`` points at a time, from
    its state's rows ``states``: ``PointDistributions.rows``), then the depth-order visibility of its points."""
    H = pix.shape[0]
    chunks = states.shape[1]
    rows = np.empty(_ROWS * _CHUNK)
    depth = np.empty(P)
    occlusion = occlusion_work(P)
    for h in range(H):
        s, g = state_index[h], pose_index[h]
        for c in range(chunks):
            start = c * _CHUNK
            n = min(_CHUNK, P - start)
            _project_pose(rot[g], trans[g], states[s, c], n, camera, ego, rows, depth, start)
            _unpack(rows, n, start, pix[h], pix_cov[h], flow[h], flow_cov[h], visibility[h])
        if occ_radius > 0.0:
            self_occlusion(pix[h], depth, camera[1] * occ_radius, occ_depth, visibility[h], occlusion)


# The projection runs on rows of points (one row per quantity) of a fixed length: with the rows' offsets known
# constants, the compiler sees one array where it saw dozens of streams that might overlap, and runs the pass on
# vectors of points (it ran one point at a time on the interleaved arrays). 136 points a chunk: the default
# model's 120 in one, and rows that do not start a multiple of 4 KiB apart (the CPU would take their loads and
# stores for dependent).
_CHUNK = 136
_STATE_ROWS = 21   # a state's points: position, velocity and normal (3 each), the two covariances' distinct entries
_ROWS = 11         # a hypothesis's points: pixel, image velocity (2 each), the two image covariances' distinct
#                    entries (3 each), the facing test


@numba.njit(cache=True)
def _state_rows(pos, pos_cov, vel, vel_cov, normal):
    """The states' points ``(S, P, ...)`` as rows ``(S, chunks, _STATE_ROWS * _CHUNK)``, ``_CHUNK`` points a
    chunk (the last one's tail unused)."""
    S, P = pos.shape[0], pos.shape[1]
    out = np.zeros((S, -(-P // _CHUNK), _STATE_ROWS * _CHUNK))
    for s in range(S):
        for p in range(P):
            c, i = divmod(p, _CHUNK)
            row = out[s, c]
            for k in range(3):
                row[k * _CHUNK + i], row[(3 + k) * _CHUNK + i] = pos[s, p, k], vel[s, p, k]
                row[(6 + k) * _CHUNK + i] = normal[s, p, k]
            for k, (a, b) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
                row[(9 + k) * _CHUNK + i], row[(15 + k) * _CHUNK + i] = pos_cov[s, p, a, b], vel_cov[s, p, a, b]
    return out


@numba.njit(inline="always", fastmath={"contract"})
def _sandwich(A0, A1, A2, B0, B1, B2, c00, c01, c02, c11, c12, c22):
    """The distinct entries of ``J C J^T`` for ``J``'s rows ``A``, ``B`` and a symmetric ``C``, as ``(J C) J^T``."""
    ta0, ta1, ta2 = A0 * c00 + A1 * c01 + A2 * c02, A0 * c01 + A1 * c11 + A2 * c12, A0 * c02 + A1 * c12 + A2 * c22
    tb0, tb1, tb2 = B0 * c00 + B1 * c01 + B2 * c02, B0 * c01 + B1 * c11 + B2 * c12, B0 * c02 + B1 * c12 + B2 * c22
    return ta0 * A0 + ta1 * A1 + ta2 * A2, ta0 * B0 + ta1 * B1 + ta2 * B2, tb0 * B0 + tb1 * B1 + tb2 * B2


@numba.njit(cache=True, fastmath={"contract"}, error_model="numpy")
def _project_pose(rot, trans, pts, n, camera, ego, rows, depth, start):
    """One hypothesis, ``n`` points of a chunk (``pts``: ``_state_rows``' rows): X = R x + t,
    Xdot = R xdot - v_c - w_c x X, u = pi(X), the covariances mapped by J = d(u)/dX R as ``(J Sigma) J^T`` (one
    fused pass over scalars), the facing test, into ``rows`` (``_ROWS`` rows of ``_CHUNK``), and the depths into
    ``depth[start:start + n]``."""
    C = _CHUNK
    fx, fy, cx, cy = camera[0], camera[1], camera[2], camera[3]
    e0, e1, e2, w0, w1, w2 = ego[0], ego[1], ego[2], ego[3], ego[4], ego[5]
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    t0, t1, t2 = trans[0], trans[1], trans[2]
    for p in range(n):
        x0, x1, x2 = pts[p], pts[C + p], pts[2 * C + p]
        X0 = t0 + r00 * x0 + r01 * x1 + r02 * x2
        X1 = t1 + r10 * x0 + r11 * x1 + r12 * x2
        X2 = t2 + r20 * x0 + r21 * x1 + r22 * x2
        v0, v1, v2 = pts[3 * C + p], pts[4 * C + p], pts[5 * C + p]
        Xd0 = r00 * v0 + r01 * v1 + r02 * v2 - e0 - (w1 * X2 - w2 * X1)
        Xd1 = r10 * v0 + r11 * v1 + r12 * v2 - e1 - (w2 * X0 - w0 * X2)
        Xd2 = r20 * v0 + r21 * v1 + r22 * v2 - e2 - (w0 * X1 - w1 * X0)
        n0, n1, n2 = pts[6 * C + p], pts[7 * C + p], pts[8 * C + p]
        n_dot_x = ((r00 * n0 + r01 * n1 + r02 * n2) * X0 + (r10 * n0 + r11 * n1 + r12 * n2) * X1
                   + (r20 * n0 + r21 * n1 + r22 * n2) * X2)
        z = X2
        depth[start + p] = z
        rows[10 * C + p] = 1.0 if (n_dot_x < 0.0) & (z > MIN_DEPTH) else 0.0
        z = z if z > MIN_DEPTH else 1.0
        iz = 1.0 / z
        rows[p] = fx * X0 * iz + cx
        rows[C + p] = fy * X1 * iz + cy
        # d(u, v)/dX = [[fx/z, 0, -fx X/z^2], [0, fy/z, -fy Y/z^2]]; its rows times R are (A0, A1, A2), (B0, B1, B2).
        a0, a2 = fx * iz, -fx * X0 * iz * iz
        b1, b2 = fy * iz, -fy * X1 * iz * iz
        A0, A1, A2 = a0 * r00 + a2 * r20, a0 * r01 + a2 * r21, a0 * r02 + a2 * r22
        B0, B1, B2 = b1 * r10 + b2 * r20, b1 * r11 + b2 * r21, b1 * r12 + b2 * r22
        rows[2 * C + p] = a0 * Xd0 + a2 * Xd2
        rows[3 * C + p] = b1 * Xd1 + b2 * Xd2
        rows[4 * C + p], rows[5 * C + p], rows[6 * C + p] = _sandwich(
            A0, A1, A2, B0, B1, B2, pts[9 * C + p], pts[10 * C + p], pts[11 * C + p], pts[12 * C + p],
            pts[13 * C + p], pts[14 * C + p])
        rows[7 * C + p], rows[8 * C + p], rows[9 * C + p] = _sandwich(
            A0, A1, A2, B0, B1, B2, pts[15 * C + p], pts[16 * C + p], pts[17 * C + p], pts[18 * C + p],
            pts[19 * C + p], pts[20 * C + p])


@numba.njit(cache=True)
def _unpack(rows, n, start, pix, pix_cov, flow, flow_cov, visibility):
    """``_project_pose``'s rows of ``n`` points into the interleaved arrays of ``ImageDistributions`` (one
    hypothesis), from point ``start``."""
    C = _CHUNK
    for i in range(n):
        p = start + i
        pix[p, 0], pix[p, 1], flow[p, 0], flow[p, 1] = rows[i], rows[C + i], rows[2 * C + i], rows[3 * C + i]
        pix_cov[p, 0, 0], pix_cov[p, 1, 1] = rows[4 * C + i], rows[6 * C + i]
        pix_cov[p, 0, 1] = pix_cov[p, 1, 0] = rows[5 * C + i]
        flow_cov[p, 0, 0], flow_cov[p, 1, 1] = rows[7 * C + i], rows[9 * C + i]
        flow_cov[p, 0, 1] = flow_cov[p, 1, 0] = rows[8 * C + i]
        visibility[p] = rows[10 * C + i]


@numba.njit(cache=True)
def occlusion_work(P):
    """Work arrays of ``self_occlusion`` for ``P`` points: each point's cell, the cells' counts (at most
    ``4 P + 1``: above that, one cell), the points sorted by cell, each footprint's inverse squared reach and the
    gathered neighbours ``(4, P)`` (float32: ``_cover``)."""
    return (np.empty(P, dtype=np.int64), np.empty(4 * P + 1, dtype=np.int64), np.empty(P, dtype=np.int64),
            np.empty(P), np.empty((4, P + _PAD), dtype=np.float32))


@numba.njit(cache=True)
def _bucket(pix, visibility, lo_u, lo_v, reach, nu, nv, cell, count, members):
    """Sort the visible points into a grid of ``nu x nv`` cells of ``reach`` pixels from ``(lo_u, lo_v)``:
    point ``q``'s cell ``cell[q]`` (-1 when invisible); the points of cell ``c`` are
    ``members[count[c]:count[c + 1]]`` (a counting sort)."""
    P = len(visibility)
    n_cells = nu * nv
    for c in range(n_cells + 1):
        count[c] = 0
    for q in range(P):
        cell[q] = -1
        if visibility[q] > 0.0:
            c = min(int((pix[q, 0] - lo_u) / reach), nu - 1) * nv + min(int((pix[q, 1] - lo_v) / reach), nv - 1)
            cell[q] = c
            count[c + 1] += 1
    for c in range(n_cells):
        count[c + 1] += count[c]
    for q in range(P):
        c = cell[q]
        if c >= 0:
            members[count[c]] = q
            count[c] += 1
    for c in range(n_cells - 1, -1, -1):       # count[c] was advanced to the cell's end: shift back
        count[c + 1] = count[c]
    count[0] = 0


@numba.njit(cache=True)
def self_occlusion(pix, depth, focal_radius, min_gap, visibility, work):
    """Multiply ``visibility`` ``(P,)`` by the footprints of the nearer visible points (see ``to_image``).

    Up to ``_ALL_PAIRS`` visible points, each runs over all of them in one loop without branches, which
    vectorises. Above, the footprints' end at two radii pays: each point only looks at the grid cells (of the
    largest footprint's size) around it, the same products in a fraction of the pairs. ``work``:
    ``occlusion_work(P)``."""
    cell, count, members, inv_reach2, near = work
    P = len(depth)
    near_u, near_v, near_z, near_inv = near[0], near[1], near[2], near[3]
    reach = 0.0
    lo_u, lo_v, hi_u, hi_v = np.inf, np.inf, -np.inf, -np.inf
    n_front = 0
    for q in range(P):
        if visibility[q] > 0.0:
            reach_q = 2.0 * focal_radius / depth[q]
            inv_reach2[q] = 1.0 / (reach_q * reach_q)
            near_u[n_front], near_v[n_front], near_z[n_front], near_inv[n_front] = pix[q, 0], pix[q, 1], depth[q], \
                inv_reach2[q]
            n_front += 1
            reach = max(reach, reach_q)
            lo_u, hi_u = min(lo_u, pix[q, 0]), max(hi_u, pix[q, 0])
            lo_v, hi_v = min(lo_v, pix[q, 1]), max(hi_v, pix[q, 1])
    if n_front < 2:
        return
    if n_front <= _ALL_PAIRS:
        n = _padded(near, n_front)
        for p in range(P):
            if visibility[p] > 0.0:
                visibility[p] *= _cover(pix[p, 0], pix[p, 1], depth[p] - min_gap, near_u, near_v, near_z, near_inv, n)
        return
    nu = int((hi_u - lo_u) / reach) + 1
    nv = int((hi_v - lo_v) / reach) + 1
    if nu * nv + 1 > len(count):                # a spread-out hypothesis: fall back to one row of cells
        nu, nv = 1, 1
    _bucket(pix, visibility, lo_u, lo_v, reach, nu, nv, cell, count, members)
    # Cell by cell: the points of the 3 x 3 cells around it are gathered once into contiguous columns, and
    # each of the cell's points runs over them in a loop without branches, which vectorises.
    for c in range(nu * nv):
        if count[c + 1] == count[c]:
            continue
        cu = c // nv
        cv = c - cu * nv
        n = 0
        for iu in range(max(cu - 1, 0), min(cu + 2, nu)):
            for iv in range(max(cv - 1, 0), min(cv + 2, nv)):
                d = iu * nv + iv
                for k in range(count[d], count[d + 1]):
                    q = members[k]
                    near_u[n], near_v[n], near_z[n], near_inv[n] = pix[q, 0], pix[q, 1], depth[q], inv_reach2[q]
                    n += 1
        n = _padded(near, n)
        for k in range(count[c], count[c + 1]):
            p = members[k]
            visibility[p] *= _cover(pix[p, 0], pix[p, 1], depth[p] - min_gap, near_u, near_v, near_z, near_inv, n)


_ONE32, _TWO32 = np.float32(1.0), np.float32(2.0)
_PAD = 32      # _cover's vector loop takes 32 float32s a step (8 lanes, 4 interleaved); the rest ran one at a time


@numba.njit(cache=True)
def _padded(near, n):
    """The number of gathered points ``near`` ``(4, P + _PAD)`` padded to a multiple of ``_PAD`` with points that
    cover nothing (infinitely far)."""
    m = -(-n // _PAD) * _PAD
    near[:, n:m] = 0.0
    near[2, n:m] = np.inf
    return m


@numba.njit(cache=True, fastmath=_PRODUCTS)
def _cover(u, v, z, near_u, near_v, near_z, near_inv, n):
    """The product of the footprints over a point at pixel ``(u, v)`` of the first ``n`` gathered points nearer
    than ``z`` (the point's depth less the gap); selects, not branches, so that the loop vectorises.

    In float32, twice the lanes of doubles: each footprint ``1 - (1 - x^2)^2``, taken as ``x^2 (2 - x^2)`` (no
    cancellation at its edge), is within a few unit round-offs (6e-8) of itself for the rounded pixels."""
    u32, v32, z32 = np.float32(u), np.float32(v), np.float32(z)     # new names: numba would widen ``u`` again
    out = _ONE32
    for j in range(n):
        du = u32 - near_u[j]
        dv = v32 - near_v[j]
        d2 = (du * du + dv * dv) * near_inv[j]
        out *= d2 * (_TWO32 - d2) if (d2 < _ONE32) & (near_z[j] < z32) else _ONE32
    return out
