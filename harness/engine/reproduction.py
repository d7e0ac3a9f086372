"""Proto-symbol reproduction (mimesis): a recognised primitive's HMM generates the motion it recognised.

A primitive's HMM is a generator as well as a recogniser (Inamura, Toshima, Tanie and Nakamura, "Embodied
symbol emergence based on mimesis theory", IJRR 2004). Given the recognised primitive ``c`` and the state path
the engine recovered (its posterior over ``c``'s states per frame), the reproduction is the HMM's expected
trajectory along that path, generated from the database only:

1. **State path** (``state_path``): the engine's filtered posteriors over ``c``'s states, smoothed backwards
   with ``c``'s transition matrix (``smooth_states``: the discrete Rauch-Tung-Striebel pass, exact for an
   HMM's filtered marginals, needing no emissions). It carries the observed timing.
2. **Style** (``adapt_means``, optional): each state's mean angles moved towards the angles recovered while
   the path was in it, by maximum a posteriori adaptation (Gauvain and Lee, IEEE Trans. Speech Audio Proc.
   1994): ``mu_k' = (tau mu_k + sum_t g_t(k) theta_t) / (tau + sum_t g_t(k))`` with ``tau = ADAPT_FRAMES``.
3. **Trajectory** (``generate_angles``): per frame the path's moment-matched Gaussian over angles and their
   rates, and the smooth trajectory that is most probable under both (maximum-likelihood parameter generation
   with dynamic features, Tokuda et al., ICASSP 2000): per angle, minimise
   ``sum_t (theta_t - m_t)^2 / v_t + (D theta)_t - r_t)^2 / w_t`` with ``D`` the central difference (the
   features' own definition of the rate), a banded linear system.
4. **Body and frame** (``reproduce``): the base orientation integrates the path's expected angular velocity
   from a start heading; the base position grounds the generated poses on the chosen body
   (``harness.body.grounding``: lowest foot point on the floor, supporting foot still), so that a reproduction
   in another body scale keeps its feet on the floor and steps as far as its legs reach. Flight is not
   reproduced (the reproduction stays in contact, as a robot would). ``mirror`` performs it with the other side.

``class_mean`` is the baseline: the same generation along the class's expected state durations (no
observation), stretched to the demonstration's length.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

from harness import geometry
from harness.body.grounding import ground
from harness.body.model import BodyModel
from harness.engine.database import MotionDatabase
from harness.engine.features import ANGLE_RATES, ANGLES, BASE_ANGULAR, mirror_features, mirror_variances
from harness.errors import EngineError
from harness.motion.motion import Motion

ADAPT_FRAMES = 10.0     # tau: a state's prior mean weighs as much as this many frames of recovered angles
                        # (Gauvain and Lee 1994 use prior weights of this order; see docs/reproduction.md)


def _class_index(db: MotionDatabase, label: str) -> int:
    classes = list(db.classes_)
    if label not in classes:
        raise EngineError(f"unknown primitive {label!r} (database: {', '.join(classes)})")
    return classes.index(label)


def smooth_states(transmat: np.ndarray, filtered: np.ndarray) -> np.ndarray:
    """``p(k_t | y_0..T-1)`` ``(T, K)`` from filtered posteriors ``p(k_t | y_0..t)`` ``(T, K)`` of an HMM with
    transitions ``(K, K)``: ``g_t = f_t * (A @ (g_{t+1} / (f_t A)))`` backwards from ``g_{T-1} = f_{T-1}``."""
    f = np.asarray(filtered, dtype=float)
    A = np.asarray(transmat, dtype=float)
    out = np.empty_like(f)
    out[-1] = f[-1]
    for t in range(len(f) - 2, -1, -1):
        predicted = f[t] @ A
        ratio = np.divide(out[t + 1], predicted, out=np.zeros_like(predicted), where=predicted > 1e-300)
        g = f[t] * (A @ ratio)
        total = g.sum()
        out[t] = g / total if total > 0 else f[t]
    return out


def state_path(db: MotionDatabase, joint_posterior: np.ndarray, label: str) -> np.ndarray:
    """The smoothed state path ``(T, K)`` of primitive ``label`` from the engine's joint posteriors
    ``(T, C, K)`` over (primitive, state): each frame's posterior over the primitive's states, smoothed."""
    c = _class_index(db, label)
    post = np.asarray(joint_posterior, dtype=float)[:, c, :]
    total = post.sum(axis=1, keepdims=True)
    # Frames where the primitive had no mass at all carry no information about its states: uniform.
    filtered = np.where(total > 1e-300, post / np.maximum(total, 1e-300), 1.0 / post.shape[1])
    return smooth_states(db.transmat_[c], filtered)


def expected_path(transmat: np.ndarray, n_frames: int) -> np.ndarray:
    """A one-hot state path ``(T, K)`` through every state in order, each for its expected dwell
    ``1 / (1 - a_kk)`` (an absorbing state: the median of the others), stretched to ``n_frames``."""
    A = np.asarray(transmat, dtype=float)
    stay = np.diag(A)
    dwell = np.where(stay < 1.0, 1.0 / np.maximum(1.0 - stay, 1e-9), np.nan)
    dwell = np.where(np.isnan(dwell), np.nanmedian(dwell) if np.isfinite(dwell).any() else 1.0, dwell)
    edges = np.concatenate([[0.0], np.cumsum(dwell)]) / dwell.sum() * n_frames
    k = np.clip(np.searchsorted(edges, np.arange(n_frames) + 0.5, side="right") - 1, 0, len(A) - 1)
    return np.eye(len(A))[k]


def adapt_means(means: np.ndarray, path: np.ndarray, angles: np.ndarray, prior_frames: float | None = None
                ) -> np.ndarray:
    """The states' feature means ``(K, D)`` with their angle part moved towards recovered angles ``(T, 50)``
    by MAP adaptation along the path ``(T, K)`` (module docstring, step 2)."""
    prior_frames = ADAPT_FRAMES if prior_frames is None else prior_frames
    out = np.array(means, dtype=float)
    counts = path.sum(axis=0)                                          # (K,) frames spent in each state
    sums = path.T @ np.asarray(angles, dtype=float)                    # (K, 50)
    out[:, ANGLES] = (prior_frames * out[:, ANGLES] + sums) / (prior_frames + counts)[:, None]
    return out


def _difference(n: int, fps: float) -> sparse.csr_matrix:
    """``(n, n)`` finite-difference rates: central inside, one-sided at the ends (``np.gradient``)."""
    d = sparse.lil_matrix((n, n))
    for t in range(n):
        lo, hi = max(t - 1, 0), min(t + 1, n - 1)
        if hi > lo:
            d[t, lo], d[t, hi] = -fps / (hi - lo), fps / (hi - lo)
    return d.tocsr()


def generate_angles(means: np.ndarray, covars: np.ndarray, path: np.ndarray, fps: float) -> np.ndarray:
    """The most probable smooth angles ``(T, 50)`` along a state path ``(T, K)`` of states with feature means
    and variances ``(K, 106)`` (module docstring, step 3)."""
    path = np.asarray(path, dtype=float)
    n = len(path)

    def moments(sl):
        m = path @ means[:, sl]
        v = path @ (covars[:, sl] + means[:, sl] ** 2) - m**2
        return m, np.maximum(v, 1e-12)

    m, v = moments(ANGLES)
    r, w = moments(ANGLE_RATES)
    if n < 2:
        return m
    D = _difference(n, fps)
    out = np.empty_like(m)
    for j in range(m.shape[1]):
        A = sparse.diags(1.0 / v[:, j]) + D.T @ sparse.diags(1.0 / w[:, j]) @ D
        b = m[:, j] / v[:, j] + D.T @ (r[:, j] / w[:, j])
        out[:, j] = spsolve(A.tocsc(), b)
    return out


def reproduce(db: MotionDatabase, body: BodyModel, label: str, path: np.ndarray, fps: float, *,
              start_xy: np.ndarray | None = None, start_heading: float = 0.0, mirror: bool = False,
              angles: np.ndarray | None = None) -> Motion:
    """Reproduce primitive ``label`` along state path ``path`` ``(T, K)`` on ``body`` in a world frame (z up,
    floor at z = 0), starting at ``start_xy`` (m) facing ``start_heading`` (rad).

    angles: the demonstrator's recovered angles ``(T, 50)``; when given, the states' means are adapted to them
    first (its style). mirror: perform it with the other side.
    """
    c = _class_index(db, label)
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[1] != db.means_.shape[1] or len(path) < 2:
        raise EngineError(f"state path must be (T >= 2, {db.means_.shape[1]}), got {path.shape}")
    means = db.means_[c] if angles is None else adapt_means(db.means_[c], path, angles)
    covars = db.covars_[c]
    if mirror:
        # The mirrored states generate the mirrored motion: the generation is per angle and linear in the
        # means, so a signed permutation of the states' features permutes and signs its output.
        means, covars = mirror_features(means), mirror_variances(covars)
    theta = generate_angles(means, covars, path, fps)
    omega = path @ means[:, BASE_ANGULAR]                              # (T, 3) base frame, rad/s
    theta = np.clip(theta, body.lower, body.upper)
    quat = np.empty((len(path), 4))
    quat[0] = geometry.yaw(np.array(start_heading))
    step = geometry.exp(omega[:-1] / fps)
    for t in range(1, len(path)):
        quat[t] = geometry.normalize(geometry.multiply(quat[t - 1], step[t - 1]))
    base = ground(body, theta, quat).positions(start_xy)
    qpos = body.qpos(theta, base_pos=base, base_quat=quat)
    side = "mirrored " if mirror else ""
    return Motion(qpos=qpos, fps=fps, label=label, source=f"reproduction: {side}{label} from the database")


def class_mean(db: MotionDatabase, body: BodyModel, label: str, n_frames: int, fps: float) -> Motion:
    """The class's mean trajectory (the baseline): the generation along ``expected_path``, ``n_frames`` long,
    through the first chain (the demonstrations' own side; a both-handed database's second chain mirrors it)."""
    c = _class_index(db, label)
    K = db.n_states
    path = np.zeros((n_frames, db.means_.shape[1]))
    path[:, :K] = expected_path(db.transmat_[c, :K, :K], n_frames)
    return reproduce(db, body, label, path, fps)


def recovered_world(body: BodyModel, qpos_cam: np.ndarray, gravity: np.ndarray | None = None) -> np.ndarray:
    """The engine's estimate ``(T, 57)`` (base in the camera frame) in the demonstrator's recovered world frame:
    z up (against ``gravity`` ``(3,)``, camera frame, when the observation gives it; else along the recovered
    body's own vertical at the first frame, the demonstrator assumed upright there), x along the camera's
    viewing direction on the floor, the origin on the floor below the first frame's pelvis (the floor at the
    first frame's lowest foot point)."""
    q = np.asarray(qpos_cam, dtype=float)
    rot0 = geometry.to_matrix(q[0, 3:7])
    up = -np.asarray(gravity, dtype=float) if gravity is not None else rot0[:, 2]
    up = up / np.linalg.norm(up)
    view = np.array([0.0, 0.0, 1.0]) - up[2] * up                     # the optical axis on the floor
    if np.linalg.norm(view) < 1e-6:                                    # looking straight down: any x will do
        view = np.array([1.0, 0.0, 0.0]) - up[0] * up
    x = view / np.linalg.norm(view)
    world = np.stack([x, np.cross(up, x), up])                         # rows: world axes in camera coordinates
    out = q.copy()
    out[:, :3] = q[:, :3] @ world.T
    out[:, 3:7] = geometry.from_matrix(world @ geometry.to_matrix(q[:, 3:7]))
    floor = ground(body, out[:1, 7:], out[:1, 3:7]).height[0]          # base height with the feet on the floor
    out[:, :3] -= np.array([out[0, 0], out[0, 1], out[0, 2] - floor])
    return out
