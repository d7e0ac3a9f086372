"""Particle clouds over the baselink pose in camera coordinates (position + unit quaternion).

One cloud belongs to one pose track. Each frame it is moved by a **mixture proposal**: a share ``1 - alpha``
of the new particles comes from the motion model (an ancestor drawn by its weight, moved by the base velocity
the track's belief predicts, ``t' = t + R v dt``, ``R' = R exp(omega dt)``, minus the camera's own motion, plus
Gaussian process noise), the share ``alpha`` from a Gaussian ``g`` around a guide pose (the pose recovery found
in the previous frame, moved the same way). Every new particle ``x`` is importance-weighted by

    w(x) ∝ p(y | x) π(x) / q(x),   π(x) = sum_i w_i k(x | x_i),   q(x) = (1 - alpha) π(x) + alpha g(x)

with ``k`` the transition density (Gaussian in position and in the rotation vector of the relative
rotation): the marginal particle filter's weights, so that guided particles never enter the cloud unweighted.
With ``alpha = 0`` this is the bootstrap filter with resampling at every frame.

Process noise is isotropic in rotation, or, when the camera knows gravity, split into a yaw part about the
known vertical and a small tilt part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from harness.engine.logsum import logsumexp
from harness.engine.vector_math import FAST, atan_ratio, exp_into

from harness import geometry
from harness.errors import EngineError
from harness.pinhole import Intrinsics

# Camera axes (OpenCV: x right, y down, z forward) of a level camera looking along the world +x axis of a
# z-up world: world-from-camera columns are the camera axes in world coordinates.
_LEVEL_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def effective_sample_size(weights: np.ndarray) -> float:
    """``1 / sum w^2`` of normalised weights."""
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    return float(1.0 / np.sum(w * w))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Indices ``(n,)`` (default ``n = len(weights)``) drawn by systematic resampling: one uniform offset,
    ``n`` evenly spaced pointers."""
    w = np.asarray(weights, dtype=float)
    n = len(w) if n is None else int(n)
    out = np.empty(n, dtype=np.int64)
    _resampled(w, np.array([0, len(w)]), np.array([rng.random()]), n, out)
    return out


@numba.njit(cache=True)
def _resampled(weights, starts, offsets, n, out):
    """Systematic resampling of each segment ``j`` of ``weights`` (``starts[j]:starts[j + 1]``) with the uniform
    offset ``offsets[j]``: ``n`` indices into ``weights`` in ``out[j n:(j + 1) n]``. Pointer ``i`` takes the first
    particle whose cumulative share exceeds ``(offset + i) / n`` (the shares' last sum taken as exactly one),
    found by one walk, since the pointers ascend."""
    for j in range(len(offsets)):
        a, b = starts[j], starts[j + 1]
        total = 0.0
        for k in range(a, b):
            total += weights[k]
        k = a
        cum = weights[a] / total
        for i in range(n):
            pointer = (offsets[j] + i) / n
            while k < b - 1 and cum <= pointer:
                k += 1
                cum += weights[k] / total
            out[j * n + i] = k


def camera_pitch(elevation: np.ndarray) -> np.ndarray:
    """World-from-camera rotations ``(..., 3, 3)`` of a camera looking along world +x, pitched down by
    ``elevation`` (rad), without roll."""
    elevation = np.asarray(elevation, dtype=float)
    c, s = np.cos(elevation), np.sin(elevation)
    pitch = np.zeros(elevation.shape + (3, 3))
    pitch[..., 0, 0] = 1.0
    pitch[..., 1, 1], pitch[..., 1, 2] = c, s
    pitch[..., 2, 1], pitch[..., 2, 2] = -s, c
    return _LEVEL_CAMERA @ pitch


def upright_orientations(heading: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    """Camera-frame quaternions ``(N, 4)`` of an upright body under cameras ``world_from_camera``
    ``(N, 3, 3)`` (or one ``(3, 3)``) whose world looks along +x; ``heading`` (rad, about world up) 0 puts the
    body's forward axis along the camera's horizontal viewing direction (the camera sees its back)."""
    heading = np.asarray(heading, dtype=float)
    cam_from_body = np.swapaxes(world_from_camera, -1, -2) @ geometry.to_matrix(geometry.yaw(heading))
    return geometry.from_matrix(cam_from_body)


def level_world(gravity: np.ndarray) -> np.ndarray:
    """A world-from-camera rotation ``(3, 3)`` whose world z is against ``gravity`` (a unit vector in the camera
    frame) and whose world x is the camera's viewing direction projected on the floor: the frame in which
    ``upright_orientations`` places bodies when the camera knows its tilt."""
    up = -np.asarray(gravity, dtype=float)
    fwd = np.array([0.0, 0.0, 1.0]) - up[2] * up
    if np.linalg.norm(fwd) < 1e-6:          # looking straight down: any horizontal axis will do
        fwd = np.array([0.0, 1.0, 0.0]) - up[1] * up
    fwd /= np.linalg.norm(fwd)
    left = np.cross(up, fwd)
    return np.stack([fwd, left, up], axis=0)   # rows: world axes in camera coordinates


@dataclass
class ParticleCloud:
    """Pose hypotheses ``positions (N, 3)`` (m, camera frame), ``quats (N, 4)`` (camera from base) and
    normalised ``log_weights (N,)``."""

    positions: np.ndarray
    quats: np.ndarray
    log_weights: np.ndarray

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def weights(self) -> np.ndarray:
        return np.exp(self.log_weights)

    def take(self, index: np.ndarray) -> "ParticleCloud":
        """The particles at ``index``, equally weighted."""
        n = len(index)
        return ParticleCloud(self.positions[index].copy(), self.quats[index].copy(), np.full(n, -np.log(n)))

    def reweight(self, log_likelihood: np.ndarray) -> float:
        """Multiply the weights by likelihoods ``(N,)`` (log) and normalise; returns the log of the weighted
        mean likelihood (this frame's particle estimate of the marginal likelihood)."""
        return float(reweight_many([self], [log_likelihood])[0])

    def estimate(self, mode_radius: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean position ``(3,)`` and Markley average orientation ``(4,)`` of the heaviest mode
        (``settled``)."""
        pos, quat, _ = settled([self], MODE_RADIUS if mode_radius is None else mode_radius)
        return pos[0], quat[0]


def reweight_many(clouds: list[ParticleCloud], log_likelihoods: list[np.ndarray]) -> np.ndarray:
    """``ParticleCloud.reweight`` of each cloud by its likelihoods, in one compiled pass (a few numpy calls per
    cloud cost more than the arithmetic with dozens of tracks); returns each cloud's log mean likelihood ``(J,)``.
    A likelihood that is not finite counts as ``-1e300`` (a particle that explains nothing keeps a weight of zero
    without making the sum undefined)."""
    if len({id(c) for c in clouds}) < len(clouds):
        raise EngineError("a cloud is given twice: each track must hold its own (it would be weighed once)")
    ll = [np.asarray(x, dtype=float) for x in log_likelihoods]
    for cloud, x in zip(clouds, ll):
        if x.shape != (len(cloud),):
            raise EngineError(f"expected {len(cloud)} log-likelihoods, got {x.shape}")
    starts = np.concatenate([[0], np.cumsum([len(c) for c in clouds])])
    log_w = np.concatenate([c.log_weights for c in clouds])
    norms = np.empty(len(clouds))
    _reweighted(log_w, np.concatenate(ll), starts, norms)
    for j, cloud in enumerate(clouds):
        cloud.log_weights = log_w[starts[j]:starts[j + 1]]
    return norms


@numba.njit(cache=True)
def _reweighted(log_w, ll, starts, norms):
    """Each segment of ``log_w`` plus its ``ll`` (``starts`` as ``_resampled``), normalised in place: ``norms[j]``
    is the segment's ``log sum exp`` (about its largest term; zero where that is not finite)."""
    for j in range(len(starts) - 1):
        a, b = starts[j], starts[j + 1]
        top = -np.inf
        for i in range(a, b):
            log_w[i] += ll[i] if np.isfinite(ll[i]) else -1e300
            top = max(top, log_w[i])
        top = top if np.isfinite(top) else 0.0
        total = 0.0
        for i in range(a, b):
            total += np.exp(log_w[i] - top)
        norms[j] = np.log(total) + top
        for i in range(a, b):
            log_w[i] -= norms[j]


MODE_RADIUS = np.deg2rad(45.0)      # a cloud's mode: the particles this close in orientation to its centre


_CENTRES = 10      # the heaviest particles ``settled`` tries as a cloud's mode centre


def settled(clouds: list[ParticleCloud], mode_radius: float = MODE_RADIUS
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each cloud's pose estimate and spread: ``(J, 3)`` weighted mean positions and ``(J, 4)`` Markley average
    orientations (the top eigenvector of ``sum w q q^T``, ``w >= 0``) of its heaviest mode, and ``(J, 3)`` the
    weighted per-axis standard deviations of all its positions (m).

    The heaviest mode: the particles within ``mode_radius`` of the candidate centre (one of the ten heaviest
    particles) that gathers the most weight. A cloud may hold mirrored modes, and the mean of two modes is
    neither. The moments are one compiled pass per cloud and the eigenproblems one batched call (with a few
    dozen tracks, numpy's calls per cloud cost more than their arithmetic)."""
    J = len(clouds)
    positions, spreads, moments = np.empty((J, 3)), np.empty((J, 3)), np.empty((J, 4, 4))
    sizes = [len(c) for c in clouds]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    w = np.exp(np.concatenate([c.log_weights for c in clouds]))
    centres = np.zeros((J, _CENTRES), dtype=np.int64)
    if len(set(sizes)) == 1 and sizes[0] > _CENTRES:      # the clouds of one frame share their size
        centres[:] = np.argpartition(w.reshape(J, sizes[0]), -_CENTRES, axis=1)[:, -_CENTRES:]
    else:
        for j, n in enumerate(sizes):
            own = w[starts[j]:starts[j + 1]]
            picked = np.argpartition(own, -_CENTRES)[-_CENTRES:] if n > _CENTRES else np.arange(n)
            centres[j, :len(picked)] = picked
    _modes_moments(np.concatenate([c.positions for c in clouds]), np.concatenate([c.quats for c in clouds]), w,
                   starts, centres, np.cos(0.5 * mode_radius), positions, spreads, moments)
    _, vec = np.linalg.eigh(moments)
    quats = vec[:, :, -1]
    return positions, quats * np.where(quats[:, :1] >= 0, 1.0, -1.0), spreads


@numba.njit(cache=True)
def _modes_moments(positions, quats, w, starts, centres, cos_half, mean, spread, moments):
    """``_mode_moments`` of every cloud, the clouds' particles concatenated (cloud ``j``: rows ``starts[j]`` to
    ``starts[j + 1]``; its candidate centres the first ``min(size, centres.shape[1])`` of ``centres[j]``, indices
    within it): one call a frame instead of one per track."""
    for j in range(len(starts) - 1):
        a, b = starts[j], starts[j + 1]
        n = min(b - a, centres.shape[1])
        _mode_moments(positions[a:b], quats[a:b], w[a:b], centres[j, :n], cos_half, mean[j], spread[j], moments[j])


@numba.njit(cache=True)
def _mode_moments(positions, quats, w, centres, cos_half, mean, spread, moments):
    """One cloud's part of ``settled``: the mode's mean position into ``mean``, its quaternions' weighted second
    moment into ``moments`` ``(4, 4)`` and the whole cloud's positional spread into ``spread``. Unit quaternions
    ``a``, ``b`` are within angle ``r`` of each other when ``|a . b| >= cos(r / 2)``; of centres that gather
    the same weight, the first."""
    N = len(w)
    best, best_mass = 0, -1.0
    for i in range(len(centres)):
        c = quats[centres[i]]
        mass = 0.0
        for n in range(N):
            q = quats[n]
            if abs(c[0] * q[0] + c[1] * q[1] + c[2] * q[2] + c[3] * q[3]) >= cos_half:
                mass += w[n]
        if mass > best_mass:
            best, best_mass = i, mass
    c = quats[centres[best]]
    mean[:] = 0.0
    moments[:] = 0.0
    for n in range(N):
        q = quats[n]
        if abs(c[0] * q[0] + c[1] * q[1] + c[2] * q[2] + c[3] * q[3]) >= cos_half:
            wn = w[n] / best_mass
            for a in range(3):
                mean[a] += wn * positions[n, a]
            for a in range(4):
                for b in range(4):
                    moments[a, b] += wn * q[a] * q[b]
    total = 0.0
    centre = np.zeros(3)
    for n in range(N):
        total += w[n]
        for a in range(3):
            centre[a] += w[n] * positions[n, a]
    for a in range(3):
        centre[a] /= total
        spread[a] = 0.0
    for n in range(N):
        for a in range(3):
            d = positions[n, a] - centre[a]
            spread[a] += w[n] * d * d
    for a in range(3):
        spread[a] = np.sqrt(spread[a] / total)


def depth_guess(intr: Intrinsics, flows: np.ndarray, body_extent: float) -> float | None:
    """The depth (m) at which points spanning ``body_extent`` (m, vertically: ``model.body_extent``) span the
    flows' vertical extent (their 5-95% percentile range of ``v``), or None with fewer than two flows."""
    pts = np.asarray(flows, dtype=float).reshape(-1, 4)[:, :2]
    if len(pts) < 2:
        return None
    v_lo, v_hi = np.percentile(pts[:, 1], [5, 95])
    return intr.fy * body_extent / max(v_hi - v_lo, 1.0)


def initial_cloud(intr: Intrinsics, flows: np.ndarray, n: int, rng: np.random.Generator, *,
                  depth_range: tuple[float, float], world_from_camera: np.ndarray, body_extent: float,
                  band: tuple[float, float] = (0.35, 1.3)) -> ParticleCloud:
    """A coarse prior: the subject where the flows are, any heading, upright under the cameras
    ``world_from_camera`` (``(n, 3, 3)`` drawn by the caller from its elevation prior, or the known tilt), at a
    depth within ``depth_range`` drawn log-uniform over ``band`` times what the flows' vertical extent suggests
    (``depth_guess``, unbiased for a body seen whole; a body partly hidden, a wall hiding the legs, or crouched,
    looks farther; raised arms, nearer)."""
    lo, hi = depth_range
    if not 0 < lo < hi:
        raise EngineError(f"depth range must satisfy 0 < near < far, got {depth_range}")
    pts = np.asarray(flows, dtype=float).reshape(-1, 4)[:, :2]
    if len(pts) >= 2:
        u_lo, u_hi = np.percentile(pts[:, 0], [5, 95])
        v_lo, v_hi = np.percentile(pts[:, 1], [5, 95])
        extent = max(v_hi - v_lo, 1.0)
        guess = depth_guess(intr, flows, body_extent)
        near, far = max(lo, band[0] * guess), min(hi, band[1] * guess)
        if near >= far:
            near, far = lo, hi
        u = rng.uniform(u_lo, u_hi, n) if u_hi > u_lo else np.full(n, u_lo)
        # The base (pelvis) is in the lower part of the visible body, or below it when the legs are hidden.
        v = rng.uniform(v_lo + 0.2 * extent, v_hi + 0.3 * extent, n)
    else:
        near, far = lo, hi
        u = rng.uniform(0, intr.width, n)
        v = rng.uniform(0, intr.height, n)
    z = np.exp(rng.uniform(np.log(near), np.log(far), n))
    positions = np.stack([(u - intr.cx) * z / intr.fx, (v - intr.cy) * z / intr.fy, z], axis=1)
    quats = upright_orientations(rng.uniform(-np.pi, np.pi, n), world_from_camera)
    return ParticleCloud(positions, quats, np.full(n, -np.log(n)))


@dataclass(frozen=True)
class ProcessNoise:
    """Random-walk noise of the base pose per sqrt(second): position (m), rotation (rad) about any axis, or,
    when ``up`` (the world's up axis in the camera frame) is known, ``rotation`` about ``up`` (yaw) and
    ``tilt`` about the horizontal axes."""

    position: float
    rotation: float
    tilt: float | None = None
    up: np.ndarray | None = None

    def rotation_std(self, dt: float) -> np.ndarray:
        """Per-axis standard deviations ``(3,)`` of the rotation noise, in the noise frame (``frame``)."""
        sd = np.sqrt(dt)
        if self.up is None:
            return np.full(3, self.rotation * sd)
        return np.array([self.tilt * sd, self.tilt * sd, self.rotation * sd])

    def frame(self) -> np.ndarray:
        """Camera-from-noise rotation ``(3, 3)``: columns two horizontal axes and up (identity without ``up``)."""
        if self.up is None:
            return np.eye(3)
        return level_world(-self.up).T


def motion_mean(positions: np.ndarray, quats: np.ndarray, base_linear: np.ndarray, base_angular: np.ndarray,
                dt: float, camera_motion: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The deterministic part of the motion model: poses moved for ``dt`` s by base velocities (base frame,
    ``(3,)`` or ``(N, 3)``) and against the camera's own motion ``(6,)`` (its linear and angular velocity in
    its frame: points move by ``-(v_c + w_c x X) dt`` and rotate by ``-w_c dt``)."""
    n = len(positions)
    rot = geometry.to_matrix(quats)
    v = np.broadcast_to(np.asarray(base_linear, dtype=float), (n, 3))
    w = np.broadcast_to(np.asarray(base_angular, dtype=float), (n, 3))
    pos = positions + np.einsum("nij,nj->ni", rot, v) * dt
    q = geometry.multiply(quats, geometry.exp(w * dt))
    if camera_motion is not None:
        vc, wc = camera_motion[:3], camera_motion[3:]
        pos = pos - (vc + np.cross(wc, pos)) * dt
        q = geometry.multiply(geometry.exp(np.broadcast_to(-wc * dt, (n, 3))), q)
    return pos, geometry.normalize(q)


@numba.njit(cache=True, fastmath=FAST, error_model="numpy")
def pose_mixture_log_density(pos, quat, mean_pos, mean_quat, log_w, pos_std, rot_std, frame):
    """``(N,)``: log density of poses ``pos (N, 3)``, ``quat (N, 4)`` under the mixture of Gaussians centred on
    ``K`` poses ``mean_pos (K, 3)``, ``mean_quat (K, 4)`` with log weights ``log_w (K,)``: independent in
    position (per-axis ``pos_std``, camera axes) and in the rotation vector ``log(R R_mean^T)`` expressed in
    ``frame`` (per-axis ``rot_std``). The noise is applied on the left in the camera frame (see ``propose``):
    ``R = exp(e) R_mean``, ``e`` in camera axes.

    The rotation vector of a unit quaternion ``(w, v)``, ``w >= 0``, is ``theta v / |v|`` with
    ``theta = 4 atan(|v| / (1 + w))`` (the quarter-angle tangent), i.e. ``4 / (1 + w) atan(t) / t`` times
    ``v``: no division by ``|v|``, and a loop over the ``K`` centres that vectorises (``vector_math``)."""
    N, K = len(pos), len(mean_pos)
    out = np.empty(N)
    log_norm = -3.0 * np.log(2.0 * np.pi)
    for j in range(3):
        log_norm -= np.log(pos_std[j]) + np.log(rot_std[j])
    ip0, ip1, ip2 = 1.0 / pos_std[0], 1.0 / pos_std[1], 1.0 / pos_std[2]
    # dr = (e @ frame) / rot_std: f_ji = frame_ij / rot_std_j, as scalars (loop invariants LLVM need not reload).
    f00, f01, f02 = frame[0, 0] / rot_std[0], frame[1, 0] / rot_std[0], frame[2, 0] / rot_std[0]
    f10, f11, f12 = frame[0, 1] / rot_std[1], frame[1, 1] / rot_std[1], frame[2, 1] / rot_std[1]
    f20, f21, f22 = frame[0, 2] / rot_std[2], frame[1, 2] / rot_std[2], frame[2, 2] / rot_std[2]
    # The centres as columns (contiguous loads), their rotations conjugated.
    c = np.empty((8, K))
    for k in range(K):
        c[0, k], c[1, k], c[2, k] = mean_pos[k, 0] * ip0, mean_pos[k, 1] * ip1, mean_pos[k, 2] * ip2
        c[3, k], c[4, k], c[5, k], c[6, k] = mean_quat[k, 0], -mean_quat[k, 1], -mean_quat[k, 2], -mean_quat[k, 3]
        c[7, k] = log_w[k]
    mx, my, mz, bws, bxs, bys, bzs, lws = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]
    term = np.empty(K)
    dens = np.empty(K)
    powers = np.empty(K)
    for n in range(N):
        p0, p1, p2 = pos[n, 0] * ip0, pos[n, 1] * ip1, pos[n, 2] * ip2
        aw, ax, ay, az = quat[n, 0], quat[n, 1], quat[n, 2], quat[n, 3]
        for k in range(K):
            d0, d1, d2 = p0 - mx[k], p1 - my[k], p2 - mz[k]
            bw, bx, by, bz = bws[k], bxs[k], bys[k], bzs[k]
            rw = aw * bw - ax * bx - ay * by - az * bz
            sign = 1.0 if rw >= 0.0 else -1.0              # the shorter way round
            rw *= sign
            rx = sign * (aw * bx + ax * bw + ay * bz - az * by)
            ry = sign * (aw * by - ax * bz + ay * bw + az * bx)
            rz = sign * (aw * bz + ax * by - ay * bx + az * bw)
            scale = 4.0 / (1.0 + rw) * atan_ratio(np.sqrt(rx * rx + ry * ry + rz * rz) / (1.0 + rw))
            e0, e1, e2 = scale * rx, scale * ry, scale * rz
            r0 = f00 * e0 + f01 * e1 + f02 * e2
            r1 = f10 * e0 + f11 * e1 + f12 * e2
            r2 = f20 * e0 + f21 * e1 + f22 * e2
            term[k] = lws[k] - 0.5 * (d0 * d0 + d1 * d1 + d2 * d2 + r0 * r0 + r1 * r1 + r2 * r2)
        top = term.max()
        if top == -np.inf:
            out[n] = -np.inf
            continue
        for k in range(K):
            term[k] -= top
        exp_into(term, dens, powers)
        out[n] = top + np.log(dens.sum()) + log_norm
    return out


def propose(cloud: ParticleCloud, n: int, noise: ProcessNoise, rng: np.random.Generator, *,
            base_linear: np.ndarray, base_angular: np.ndarray, dt: float, camera_motion: np.ndarray | None = None,
            guide: tuple[np.ndarray, np.ndarray] | None = None, guide_fraction: float = 0.0,
            guide_std: tuple[np.ndarray, np.ndarray] | None = None) -> ParticleCloud:
    """``n`` new particles from the mixture proposal (module docstring), with log-weights ``log π(x)/q(x)``
    normalised: multiply in the likelihood with ``ParticleCloud.reweight``.

    base_linear, base_angular: the base velocity (base frame, ``(3,)`` or ``(N, 3)``) over ``dt`` s; guide: a
    pose ``(position (3,), quaternion (4,))`` at the *new* frame; guide_std: its per-axis position (m) and
    rotation (rad, camera axes) standard deviations.
    """
    if guide is None or guide_fraction <= 0:
        return propose_many([cloud], n, noise, rng, base_linear=np.reshape(base_linear, (-1, 3)),
                            base_angular=np.reshape(base_angular, (-1, 3)), dt=dt, camera_motion=camera_motion)[0]
    mean_pos, mean_quat = motion_mean(cloud.positions, cloud.quats, base_linear, base_angular, dt, camera_motion)
    pos_std = np.full(3, noise.position * np.sqrt(dt))
    rot_std = noise.rotation_std(dt)
    frame = noise.frame()
    n_guide = int(round(guide_fraction * n)) if guide is not None else 0
    n_model = n - n_guide
    parents = systematic_resample(cloud.weights, rng, n_model)
    pos = mean_pos[parents] + rng.normal(size=(n_model, 3)) * pos_std
    quat = geometry.multiply(geometry.exp((rng.normal(size=(n_model, 3)) * rot_std) @ frame.T), mean_quat[parents])
    if n_guide:
        g_pos, g_quat = guide
        g_pos_std, g_rot_std = (np.array(np.broadcast_to(np.asarray(s, dtype=float), (3,))) for s in guide_std)
        pos = np.concatenate([pos, g_pos + rng.normal(size=(n_guide, 3)) * g_pos_std])
        quat = np.concatenate([quat, geometry.multiply(geometry.exp(rng.normal(size=(n_guide, 3)) * g_rot_std),
                                                       np.broadcast_to(g_quat, (n_guide, 4)))])
    quat = geometry.normalize(quat)
    log_w = np.full(n, -np.log(n))
    if n_guide:
        prior = pose_mixture_log_density(pos, quat, mean_pos, mean_quat, cloud.log_weights, pos_std, rot_std, frame)
        g = pose_mixture_log_density(pos, quat, np.asarray(guide[0], dtype=float)[None],
                                     np.asarray(guide[1], dtype=float)[None], np.zeros(1), g_pos_std, g_rot_std,
                                     np.eye(3))
        a = n_guide / n
        q = np.logaddexp(np.log1p(-a) + prior, np.log(a) + g) if a < 1 else g
        log_w = prior - q
        log_w -= logsumexp(log_w)
    return ParticleCloud(pos, quat, log_w)


def propose_many(clouds: list[ParticleCloud], n: int, noise: ProcessNoise, rng: np.random.Generator, *,
                 base_linear: np.ndarray, base_angular: np.ndarray, dt: float,
                 camera_motion: np.ndarray | None = None) -> list[ParticleCloud]:
    """The bootstrap proposal (``propose`` without a guide) for several clouds at once: ``n`` new equally
    weighted particles each, cloud ``j`` moved by its own base velocity ``base_linear[j]``,
    ``base_angular[j]`` (base frame; ``(J, 3)`` each, or ``(1, 3)`` for all). One motion-model pass and one
    draw of noise for all clouds: the per-cloud work of the pose tracks is Python, not arithmetic."""
    sizes = [len(c) for c in clouds]
    owner = np.repeat(np.arange(len(clouds)), sizes)
    v = np.asarray(base_linear, dtype=float).reshape(-1, 3)
    w = np.asarray(base_angular, dtype=float).reshape(-1, 3)
    mean_pos, mean_quat = motion_mean(np.concatenate([c.positions for c in clouds]),
                                      np.concatenate([c.quats for c in clouds]), v[owner % len(v)],
                                      w[owner % len(w)], dt, camera_motion)
    parents = np.empty(len(clouds) * n, dtype=np.int64)
    _resampled(np.exp(np.concatenate([c.log_weights for c in clouds])), np.concatenate([[0], np.cumsum(sizes)]),
               rng.random(len(clouds)), n, parents)      # one offset per cloud, drawn in the clouds' order
    total = len(parents)
    pos = mean_pos[parents] + rng.normal(size=(total, 3)) * (noise.position * np.sqrt(dt))
    frame = noise.frame()
    quat = geometry.normalize(geometry.multiply(geometry.exp((rng.normal(size=(total, 3)) * noise.rotation_std(dt))
                                                             @ frame.T), mean_quat[parents]))
    log_w = np.full(n, -np.log(n))
    return [ParticleCloud(pos[j * n:(j + 1) * n], quat[j * n:(j + 1) * n], log_w.copy()) for j in range(len(clouds))]
