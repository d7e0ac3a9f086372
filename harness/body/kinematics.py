"""Forward kinematics of body-fixed points, their Jacobians w.r.t. the 50 hinge angles, and their velocities.

A point is given by the body it is fixed to (``point_body``, ``(P,)`` int, MuJoCo body ids) and its
position in that body's frame (``point_local``, ``(P, 3)`` metres). Every function takes a batch of
configurations ``(T, 57)`` (or one ``(57,)``) and a ``frame``:

- ``"world"``: the base is placed at its qpos pose; results are in world coordinates.
- ``"base"``: the base is held at the identity; results are in the base (pelvis) frame, which the
  design calls the body frame. The engine works in this frame.

Positions come from MuJoCo's ``mj_kinematics``; positions with Jacobians from the compiled walk of the kinematic
tree (``harness.body.tree``: one pass per configuration, no call per body), which tests check against MuJoCo's
sites, ``mj_jac`` at the point and finite differences.
"""

from __future__ import annotations

import mujoco
import numpy as np

from harness import geometry
from harness.body.model import NQ, BodyModel
from harness.body.surface import BOX, CAPSULE, CYLINDER, SPHERE
from harness.body.tree import points_and_jacobians
from harness.errors import BodyError

FRAMES = ("world", "base")
_IDENTITY_BASE = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])


def _as_batch(qpos: np.ndarray) -> tuple[np.ndarray, bool]:
    qpos = np.asarray(qpos, dtype=float)
    if qpos.ndim == 1:
        return qpos[None], True
    if qpos.ndim != 2 or qpos.shape[1] != NQ:
        raise BodyError(f"qpos must have shape ({NQ},) or (T, {NQ}), got {qpos.shape}")
    return qpos, False


def _check_frame(frame: str) -> None:
    if frame not in FRAMES:
        raise BodyError(f"frame must be one of {FRAMES}, got {frame!r}")


def _pose(body: BodyModel, q: np.ndarray, frame: str) -> None:
    d = body.data
    d.qpos[:] = q
    if frame == "base":
        d.qpos[:7] = _IDENTITY_BASE
    mujoco.mj_kinematics(body.model, d)


def _world_points(body: BodyModel, point_body: np.ndarray, point_local: np.ndarray) -> np.ndarray:
    d = body.data
    rot = d.xmat[point_body].reshape(-1, 3, 3)
    return d.xpos[point_body] + np.einsum("pij,pj->pi", rot, point_local)


def forward_points(body: BodyModel, qpos: np.ndarray, point_body: np.ndarray, point_local: np.ndarray,
                   frame: str = "world") -> np.ndarray:
    """Positions of body-fixed points: ``(T, 57) -> (T, P, 3)`` (or ``(57,) -> (P, 3)``), metres."""
    _check_frame(frame)
    batch, single = _as_batch(qpos)
    point_body = np.asarray(point_body, dtype=int)
    point_local = np.asarray(point_local, dtype=float).reshape(-1, 3)
    out = np.empty((len(batch), len(point_body), 3))
    for t, q in enumerate(batch):
        _pose(body, q, frame)
        out[t] = _world_points(body, point_body, point_local)
    return out[0] if single else out


def forward_points_and_jacobians(body: BodyModel, qpos: np.ndarray, point_body: np.ndarray,
                                 point_local: np.ndarray, frame: str = "world"
                                 ) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(T, P, 3)`` and Jacobians ``(T, P, 3, 50)`` (metres per radian) w.r.t. the hinge angles.

    A single configuration ``(57,)`` gives ``(P, 3)`` and ``(P, 3, 50)``. Computed by the compiled walk of the
    body's kinematic tree (``harness.body.tree``), tested against MuJoCo's ``mj_kinematics`` and ``mj_jac``.
    """
    _check_frame(frame)
    batch, single = _as_batch(qpos)
    if frame == "base":
        base_rot, base_pos = np.broadcast_to(np.eye(3), (len(batch), 3, 3)), np.zeros((len(batch), 3))
    else:
        base_rot, base_pos = geometry.to_matrix(geometry.normalize(batch[:, 3:7])), batch[:, :3]
    pos, jac = points_and_jacobians(body.tree, batch[:, body.angle_qpos_index], base_rot, base_pos,
                                    np.asarray(point_body, dtype=int), np.asarray(point_local, dtype=float).reshape(-1, 3))
    if single:
        return pos[0], jac[0]
    return pos, jac


def point_jacobians(body: BodyModel, qpos: np.ndarray, point_body: np.ndarray, point_local: np.ndarray,
                    frame: str = "world") -> np.ndarray:
    """Jacobians of point positions w.r.t. the 50 angles: ``(P, 3, 50)`` or ``(T, P, 3, 50)``."""
    return forward_points_and_jacobians(body, qpos, point_body, point_local, frame)[1]


def point_velocities(body: BodyModel, qpos: np.ndarray, angle_rates: np.ndarray, base_linear: np.ndarray,
                     base_angular: np.ndarray, point_body: np.ndarray, point_local: np.ndarray) -> np.ndarray:
    """Velocities of body-fixed points in the base frame, ``(T, P, 3)`` metres per second.

    ``xdot = J(theta) thetadot + v + omega x x`` with ``x`` the point in the base frame and ``v``,
    ``omega`` the base's linear and angular velocity expressed in the base frame (``(T, 3)`` each);
    ``angle_rates`` is ``(T, 50)`` radians per second. Single configurations give ``(P, 3)``.
    """
    pos, jac = forward_points_and_jacobians(body, qpos, point_body, point_local, frame="base")
    single = pos.ndim == 2
    if single:
        pos, jac = pos[None], jac[None]
    rates = np.asarray(angle_rates, dtype=float).reshape(len(pos), -1)
    v = np.asarray(base_linear, dtype=float).reshape(len(pos), 1, 3)
    w = np.asarray(base_angular, dtype=float).reshape(len(pos), 1, 3)
    vel = np.einsum("tpij,tj->tpi", jac, rates) + v + np.cross(w, pos)
    return vel[0] if single else vel


def body_frames(body: BodyModel, qpos: np.ndarray, frame: str = "world") -> tuple[np.ndarray, np.ndarray]:
    """Origins ``(nbody, 3)`` (metres) and orientations ``(nbody, 3, 3)`` (frame from body) of every body,
    the world body included (index 0), for one configuration ``(57,)``."""
    _check_frame(frame)
    _pose(body, np.asarray(qpos, dtype=float), frame)
    return body.data.xpos.copy(), body.data.xmat.reshape(-1, 3, 3).copy()


def body_origins(body: BodyModel, qpos: np.ndarray, frame: str = "world") -> np.ndarray:
    """Origins of every non-world body (the joint centres): ``(T, nbody - 1, 3)``; index 0 is the root."""
    ids = np.arange(1, body.model.nbody)
    return forward_points(body, qpos, ids, np.zeros((len(ids), 3)), frame)


def geom_z_range(body: BodyModel, qpos: np.ndarray, geoms: np.ndarray | None = None) -> np.ndarray:
    """Lowest and highest world height of primitive geoms: ``(T, G, 2)`` metres (``(G, 2)`` for one qpos).

    Closed forms per primitive: the support of a sphere, capsule, cylinder or box along world z. ``geoms``
    defaults to every geom of the humanoid (``body.body_geoms``).
    """
    batch, single = _as_batch(qpos)
    m, d = body.model, body.data
    geoms = body.body_geoms if geoms is None else np.asarray(geoms, dtype=int)
    gtype, size = m.geom_type[geoms], m.geom_size[geoms]
    out = np.empty((len(batch), len(geoms), 2))
    for t, q in enumerate(batch):
        _pose(body, q, "world")
        rz = d.geom_xmat[geoms].reshape(-1, 3, 3)[:, 2, :]        # world z row of each geom's rotation
        ext = np.where(gtype == SPHERE, size[:, 0], 0.0)
        ext = np.where(gtype == CAPSULE, np.abs(rz[:, 2]) * size[:, 1] + size[:, 0], ext)
        ext = np.where(gtype == CYLINDER, np.abs(rz[:, 2]) * size[:, 1]
                       + size[:, 0] * np.sqrt(np.clip(1.0 - rz[:, 2] ** 2, 0.0, 1.0)), ext)
        ext = np.where(gtype == BOX, np.sum(np.abs(rz) * size, axis=1), ext)
        centre = d.geom_xpos[geoms, 2]
        out[t, :, 0], out[t, :, 1] = centre - ext, centre + ext
    return out[0] if single else out
