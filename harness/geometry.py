"""Rotations as unit quaternions ``(..., 4)`` in MuJoCo's order (w, x, y, z), vectorised over leading axes.

A quaternion ``q`` maps vectors from a child frame into its parent frame: ``v_parent = rotate(q, v_child)``.
Angular velocities are rotation vectors per second (axis times rate).
"""

from __future__ import annotations

import numba
import numpy as np


def normalize(q: np.ndarray) -> np.ndarray:
    """``q`` divided by its norm over the last axis."""
    return _row_by_row(_normalized, q, np.shape(q)[-1])


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (first rotate by ``b``, then by ``a``)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    _hamilton(_rows(a, out.shape), _rows(b, out.shape), out.reshape(-1, 4))
    return out


def _rows(q: np.ndarray, shape: tuple) -> np.ndarray:
    """``q`` broadcast to ``shape`` as rows ``(n, 4)``, or as one row when it is a single quaternion."""
    if q.size == 4:
        return q.reshape(1, 4)
    return (q if q.shape == shape else np.broadcast_to(q, shape)).reshape(-1, 4)


# The engine calls the quaternion functions a dozen times a frame on hundreds of quaternions, where numpy's
# per-operation cost was most of their time. Their kernels (here and below) are compiled without fastmath and keep
# numpy's order of operations, and so its rounding.
@numba.njit(cache=True)
def _hamilton(a, b, out):
    """``out[i] = a[i] * b[i]`` over rows ``(n, 4)``; a one-row ``a`` or ``b`` is used for every row."""
    step_a, step_b = int(len(a) > 1), int(len(b) > 1)
    for i in range(len(out)):
        aw, ax, ay, az = a[i * step_a, 0], a[i * step_a, 1], a[i * step_a, 2], a[i * step_a, 3]
        bw, bx, by, bz = b[i * step_b, 0], b[i * step_b, 1], b[i * step_b, 2], b[i * step_b, 3]
        out[i, 0] = aw * bw - ax * bx - ay * by - az * bz
        out[i, 1] = aw * bx + ax * bw + ay * bz - az * by
        out[i, 2] = aw * by - ax * bz + ay * bw + az * bx
        out[i, 3] = aw * bz + ax * by - ay * bx + az * bw


def conjugate(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions."""
    q = np.asarray(q, dtype=float)
    out = np.empty(q.shape[:-1] + (3, 3))
    _matrices(q.reshape(-1, 4), out.reshape(-1, 3, 3))
    return out


@numba.njit(cache=True)
def _matrices(q, out):
    """``out[i]``: the rotation matrix of the unit quaternion ``q[i]``."""
    for i in range(len(q)):
        w, x, y, z = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        out[i, 0, 0], out[i, 0, 1], out[i, 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
        out[i, 1, 0], out[i, 1, 1], out[i, 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
        out[i, 2, 0], out[i, 2, 1], out[i, 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


def from_matrix(mat: np.ndarray) -> np.ndarray:
    """Unit quaternions (w >= 0) of rotation matrices ``(..., 3, 3)``, by the largest-eigenvector method."""
    mat = np.asarray(mat, dtype=float)
    m00, m01, m02 = mat[..., 0, 0], mat[..., 0, 1], mat[..., 0, 2]
    m10, m11, m12 = mat[..., 1, 0], mat[..., 1, 1], mat[..., 1, 2]
    m20, m21, m22 = mat[..., 2, 0], mat[..., 2, 1], mat[..., 2, 2]
    # Bar-Itzhack's symmetric 4x4 matrix: its top eigenvector is the quaternion, robust for any rotation.
    k = np.stack([
        np.stack([m00 - m11 - m22, m10 + m01, m20 + m02, m21 - m12], axis=-1),
        np.stack([m10 + m01, m11 - m00 - m22, m21 + m12, m02 - m20], axis=-1),
        np.stack([m20 + m02, m21 + m12, m22 - m00 - m11, m10 - m01], axis=-1),
        np.stack([m21 - m12, m02 - m20, m10 - m01, m00 + m11 + m22], axis=-1),
    ], axis=-2) / 3.0
    _, vec = np.linalg.eigh(k)
    xyzw = vec[..., -1]
    q = np.concatenate([xyzw[..., 3:4], xyzw[..., :3]], axis=-1)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``(..., 3)`` by quaternions ``(..., 4)`` (broadcasting)."""
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def exp(rotvec: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation vector ``(..., 3)`` (axis times angle, radians)."""
    return _row_by_row(_exp, rotvec, 4)


def _row_by_row(kernel, x: np.ndarray, width: int) -> np.ndarray:
    """``kernel`` (rows in, rows of ``width`` out) over the last axis of ``x``, its leading axes kept."""
    x = np.ascontiguousarray(x, dtype=float)
    out = np.empty(x.shape[:-1] + (width,))
    kernel(x.reshape(-1, x.shape[-1]), out.reshape(-1, width))
    return out


@numba.njit(cache=True)
def _exp(v, out):
    """``out[i]``: the quaternion of rotation vector ``v[i]``; ``sin(x/2)/x`` with its series near zero."""
    for i in range(len(v)):
        x, y, z = v[i, 0], v[i, 1], v[i, 2]
        angle = np.sqrt(x * x + y * y + z * z)
        half = 0.5 * angle
        scale = np.sin(half) / angle if angle > 1e-8 else 0.5 - angle * angle / 48.0
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = np.cos(half), scale * x, scale * y, scale * z


@numba.njit(cache=True)
def _normalized(q, out):
    """``out[i] = q[i] / |q[i]|``, the squares summed in order from the first (numpy's ``norm`` on a short axis)."""
    for i in range(len(q)):
        s = 0.0
        for k in range(q.shape[1]):
            s += q[i, k] * q[i, k]
        n = np.sqrt(s)
        for k in range(q.shape[1]):
            out[i, k] = q[i, k] / n


def log(q: np.ndarray) -> np.ndarray:
    """Rotation vector ``(..., 3)`` of unit quaternions, angle in [0, pi] (the shorter way round)."""
    return _row_by_row(_log, q, 3)


@numba.njit(cache=True)
def _log(q, out):
    """``out[i]``: the rotation vector of quaternion ``q[i]`` (``q`` or ``-q``, whichever has ``w >= 0``)."""
    for i in range(len(q)):
        sign = -1.0 if q[i, 0] < 0 else 1.0
        w, x, y, z = q[i, 0] * sign, q[i, 1] * sign, q[i, 2] * sign, q[i, 3] * sign
        s = np.sqrt(x * x + y * y + z * z)
        angle = 2.0 * np.arctan2(s, w)
        scale = angle / s if s > 1e-12 else 2.0 / np.maximum(w, 1e-300)
        out[i, 0], out[i, 1], out[i, 2] = scale * x, scale * y, scale * z


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle (radians, in [0, pi]) of ``a^-1 b``."""
    return np.linalg.norm(log(multiply(conjugate(a), b)), axis=-1)


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation from ``a`` (t = 0) to ``b`` (t = 1), the shorter way round."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    t = np.asarray(t, dtype=float)[..., None]
    b = b * np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return normalize(multiply(a, exp(t * log(multiply(conjugate(a), b)))))


def weighted_mean(q: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted average of quaternions ``(N, 4)``: the top eigenvector of ``sum w q q^T`` (Markley et al., 2007).

    Sign-invariant (q and -q are the same rotation); returns w >= 0.
    """
    q = np.asarray(q, dtype=float)
    w = np.ones(len(q)) if weights is None else np.asarray(weights, dtype=float)
    _, vec = np.linalg.eigh((q * w[:, None]).T @ q)
    mean = vec[:, -1]
    return mean * (1.0 if mean[0] >= 0 else -1.0)


def yaw(angle: np.ndarray) -> np.ndarray:
    """Quaternions of rotations about world z by ``angle`` (radians)."""
    half = 0.5 * np.asarray(angle, dtype=float)
    out = np.zeros(half.shape + (4,))
    out[..., 0], out[..., 3] = np.cos(half), np.sin(half)
    return out


def heading(q: np.ndarray) -> np.ndarray:
    """Heading (radians) of a z-up body: the world angle of its forward axis (x) projected on the floor."""
    fwd = rotate(q, np.array([1.0, 0.0, 0.0]))
    return np.arctan2(fwd[..., 1], fwd[..., 0])


DIFFERENCE_SCHEMES = ("central", "backward")


def finite_difference(x: np.ndarray, dt: float, scheme: str = "central") -> np.ndarray:
    """Time derivative of samples ``(T, ...)`` spaced ``dt`` seconds: central differences inside, one-sided at
    the ends; zeros for a single sample. ``scheme="backward"``: ``(x_t - x_{t-1}) / dt`` (the first sample
    takes the second's), the rate of change over the interval that ends at each sample."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return np.zeros_like(x)
    if scheme == "backward":
        d = np.diff(x, axis=0) / dt
        return np.concatenate([d[:1], d])
    if scheme != "central":
        raise ValueError(f"scheme must be one of {DIFFERENCE_SCHEMES}, got {scheme!r}")
    return np.gradient(x, dt, axis=0, edge_order=1)


def body_angular_velocity(q: np.ndarray, dt: float, scheme: str = "central") -> np.ndarray:
    """Angular velocity ``(T, 3)`` (rad/s) in the moving frame of orientations ``q (T, 4)`` (parent from body)
    sampled every ``dt`` seconds: ``log(q_a^-1 q_b) / (t_b - t_a)`` between the neighbours of each sample
    (one-sided at the ends), which is exact for a constant rate about a body-fixed axis. ``scheme="backward"``:
    between the previous sample and this one (the first sample takes the second's)."""
    q = np.asarray(q, dtype=float)
    if len(q) < 2:
        return np.zeros((len(q), 3))
    if scheme == "backward":
        w = log(multiply(conjugate(q[:-1]), q[1:])) / dt
        return np.concatenate([w[:1], w])
    if scheme != "central":
        raise ValueError(f"scheme must be one of {DIFFERENCE_SCHEMES}, got {scheme!r}")
    prev = np.concatenate([q[:1], q[:-1]])
    nxt = np.concatenate([q[1:], q[-1:]])
    span = np.full(len(q), 2.0 * dt)
    span[0] = span[-1] = dt
    return log(multiply(conjugate(prev), nxt)) / span[:, None]
