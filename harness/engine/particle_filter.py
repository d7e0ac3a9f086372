"""Particle filter over the baselink pose in camera coordinates (position + unit quaternion).

Prediction moves every particle by the base velocity that the recognition belief predicts (base frame),
``t' = t + R v dt``, ``R' = R exp(omega dt)`` (minus the camera's own motion), plus Gaussian process noise.
Weights come from the tempered flow likelihood; systematic resampling when the effective sample size falls
below a fraction of the particle count, followed by a small roughening jitter proportional to the cloud's
spread (so that a cloud that has collapsed onto a few poses can still move). The estimate is the weighted
mean position and the Markley quaternion average.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

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
    cum = np.cumsum(w / w.sum())
    cum[-1] = 1.0
    pointers = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cum, pointers, side="right")


def upright_orientations(heading: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """Camera-frame quaternions ``(N, 4)`` of an upright body seen by a camera pitched down by ``elevation``
    (rad); ``heading`` (rad, about world up) 0 puts the body's forward axis along the camera's horizontal
    viewing direction (the camera sees its back)."""
    heading, elevation = np.broadcast_arrays(np.asarray(heading, float), np.asarray(elevation, float))
    # world-from-camera = level camera pitched down about its own x axis.
    c, s = np.cos(elevation), np.sin(elevation)
    pitch = np.zeros(heading.shape + (3, 3))
    pitch[..., 0, 0] = 1.0
    pitch[..., 1, 1], pitch[..., 1, 2] = c, s
    pitch[..., 2, 1], pitch[..., 2, 2] = -s, c
    world_from_cam = _LEVEL_CAMERA @ pitch
    cam_from_body = np.swapaxes(world_from_cam, -1, -2) @ geometry.to_matrix(geometry.yaw(heading))
    return geometry.from_matrix(cam_from_body)


class ParticleFilter:
    """Baselink pose hypotheses ``positions (N, 3)``, ``quats (N, 4)`` with log-weights ``(N,)``."""

    def __init__(self, n_particles: int, rng: np.random.Generator, ess_fraction: float = 0.5,
                 position_noise: float = 0.15, rotation_noise: float = 0.3, roughening: float = 0.15):
        if n_particles < 1:
            raise EngineError(f"the particle filter needs at least one particle, got {n_particles}")
        if not 0.0 < ess_fraction <= 1.0:
            raise EngineError(f"ess_fraction must be in (0, 1], got {ess_fraction}")
        self.n = int(n_particles)
        self.rng = rng
        self.ess_fraction = ess_fraction
        self.position_noise = position_noise      # m per sqrt(s)
        self.rotation_noise = rotation_noise      # rad per sqrt(s)
        self.roughening = roughening
        self.positions = np.zeros((self.n, 3))
        self.quats = np.tile([1.0, 0.0, 0.0, 0.0], (self.n, 1))
        self.log_weights = np.full(self.n, -np.log(self.n))

    # --- initialisation -------------------------------------------------------------------------

    def initialise(self, intr: Intrinsics, flows: np.ndarray, depth_range: tuple[float, float],
                   elevation_range: tuple[float, float], body_height: float) -> None:
        """Spread the particles over a coarse prior: the subject where the flows are, at a depth within the
        given range and a band around what the flows' vertical extent suggests, any heading, upright under a
        camera pitched within ``elevation_range`` (radians)."""
        lo, hi = depth_range
        if not 0 < lo < hi:
            raise EngineError(f"depth range must satisfy 0 < near < far, got {depth_range}")
        rng, n = self.rng, self.n
        pts = np.asarray(flows, dtype=float).reshape(-1, 4)[:, :2]
        if len(pts) >= 2:
            u_lo, u_hi = np.percentile(pts[:, 0], [5, 95])
            v_lo, v_hi = np.percentile(pts[:, 1], [5, 95])
            # The flows' height suggests a depth for a body of known height. It overestimates the depth when
            # the body is partly hidden (a wall hiding the legs) or crouched, and underestimates it when the
            # arms are raised, hence the asymmetric band.
            extent = max(v_hi - v_lo, 1.0)
            guess = intr.fy * body_height / extent
            near, far = max(lo, 0.35 * guess), min(hi, 1.3 * guess)
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
        self.positions = np.stack([(u - intr.cx) * z / intr.fx, (v - intr.cy) * z / intr.fy, z], axis=1)
        self.quats = upright_orientations(rng.uniform(-np.pi, np.pi, n), rng.uniform(*elevation_range, n))
        self.log_weights = np.full(n, -np.log(n))

    # --- recursion ------------------------------------------------------------------------------

    def predict(self, base_linear: np.ndarray, base_angular: np.ndarray, dt: float,
                camera_motion: np.ndarray | None = None) -> None:
        """Move by the predicted base velocity (base frame, ``(3,)`` or ``(N, 3)``) for ``dt`` seconds."""
        rot = geometry.to_matrix(self.quats)
        v = np.broadcast_to(np.asarray(base_linear, dtype=float), (self.n, 3))
        w = np.broadcast_to(np.asarray(base_angular, dtype=float), (self.n, 3))
        pos = self.positions + np.einsum("nij,nj->ni", rot, v) * dt
        quats = geometry.multiply(self.quats, geometry.exp(w * dt))
        if camera_motion is not None:
            # The camera moves by (vc, wc) in its own frame: points move by -(vc + wc x X) dt, and rotate
            # by -wc dt.
            vc, wc = camera_motion[:3], camera_motion[3:]
            pos = pos - (vc + np.cross(wc, pos)) * dt
            quats = geometry.multiply(geometry.exp(np.broadcast_to(-wc * dt, (self.n, 3))), quats)
        sd = np.sqrt(dt)
        pos = pos + self.rng.normal(0.0, self.position_noise * sd, (self.n, 3))
        quats = geometry.multiply(quats, geometry.exp(self.rng.normal(0.0, self.rotation_noise * sd, (self.n, 3))))
        self.positions, self.quats = pos, geometry.normalize(quats)

    def update(self, log_likelihood: np.ndarray) -> None:
        """Reweight by per-particle log-likelihoods ``(N,)`` and resample if the ESS is low."""
        ll = np.asarray(log_likelihood, dtype=float)
        if ll.shape != (self.n,):
            raise EngineError(f"expected {self.n} log-likelihoods, got {ll.shape}")
        lw = self.log_weights + np.where(np.isfinite(ll), ll, -1e300)
        self.log_weights = lw - logsumexp(lw)
        if effective_sample_size(self.weights) < self.ess_fraction * self.n:
            self._resample()

    def _resample(self) -> None:
        spread = np.sqrt(np.average((self.positions - self.estimate()[0]) ** 2, axis=0, weights=self.weights))
        idx = systematic_resample(self.weights, self.rng)
        self.positions = self.positions[idx] + self.rng.normal(0.0, 1.0, (self.n, 3)) * self.roughening * spread
        self.quats = geometry.normalize(geometry.multiply(
            self.quats[idx], geometry.exp(self.rng.normal(0.0, self.roughening * 0.1, (self.n, 3)))))
        self.log_weights = np.full(self.n, -np.log(self.n))

    def inject(self, position: np.ndarray, quat: np.ndarray, fraction: float, position_std: float,
               rotation_std: float) -> None:
        """Replace the lowest-weight ``fraction`` of particles by samples around a pose found by recovery (the
        'extended' proposal); they get the median weight so that the next likelihood decides."""
        k = int(round(fraction * self.n))
        if k <= 0:
            return
        worst = np.argsort(self.log_weights)[:k]
        self.positions[worst] = position + self.rng.normal(0.0, position_std, (k, 3))
        self.quats[worst] = geometry.normalize(geometry.multiply(
            np.broadcast_to(quat, (k, 4)), geometry.exp(self.rng.normal(0.0, rotation_std, (k, 3)))))
        self.log_weights[worst] = np.median(self.log_weights)
        self.log_weights -= logsumexp(self.log_weights)

    def inject_jumps(self, fraction: float, angles: tuple[float, ...] = (np.pi, 0.5 * np.pi, -0.5 * np.pi)) -> None:
        """Kinematic-jump proposals: replace the lowest-weight ``fraction`` of particles by copies of the
        estimate turned about the body's own vertical axis (by default half and quarter turns), with the
        median weight.

        One camera cannot tell a body seen from the front from one seen from the back until the motion
        reveals it (a squat from the front and from behind give almost the same flows for many frames);
        by then resampling has emptied the other mode. Keeping a few particles in the mirrored poses lets
        the filter switch when the evidence arrives."""
        k = int(round(fraction * self.n))
        if k <= 0:
            return
        pos, quat = self.estimate()
        worst = np.argsort(self.log_weights)[:k]
        turns = np.asarray(angles)[np.arange(k) % len(angles)]
        self.positions[worst] = pos
        self.quats[worst] = geometry.multiply(np.broadcast_to(quat, (k, 4)), geometry.yaw(turns))
        self.log_weights[worst] = np.median(self.log_weights)
        self.log_weights -= logsumexp(self.log_weights)

    def select(self, log_likelihood: np.ndarray, n: int) -> None:
        """Keep ``n`` particles drawn by systematic resampling with weights from ``log_likelihood``: how a
        wide initial cloud is narrowed to the working size after the first frame."""
        ll = np.asarray(log_likelihood, dtype=float)
        idx = systematic_resample(np.exp(ll - ll.max()), self.rng, n)
        self.n = int(n)
        self.positions, self.quats = self.positions[idx], self.quats[idx]
        self.log_weights = np.full(self.n, -np.log(self.n))

    # --- read-out -------------------------------------------------------------------------------

    @property
    def weights(self) -> np.ndarray:
        return np.exp(self.log_weights)

    def estimate(self, mode_radius: float = np.deg2rad(45.0)) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean position ``(3,)`` and Markley average orientation ``(4,)`` of the heaviest mode: the
        particles within ``mode_radius`` of the candidate centre (one of the ten heaviest particles) that
        gathers the most weight. The cloud may hold mirrored modes, and the mean of two modes is neither."""
        w = self.weights
        centres = np.argsort(w)[-10:]
        near = geometry.angle_between(self.quats[None, :, :], self.quats[centres][:, None, :]) <= mode_radius
        near = near[np.argmax(near @ w)]
        w = np.where(near, w, 0.0)
        w = w / w.sum()
        return w @ self.positions, geometry.weighted_mean(self.quats, w)
