"""The body's kinematic tree as arrays, and forward kinematics of body-fixed points with their Jacobians in one
compiled pass (numba), without a MuJoCo call per configuration or per body.

The walk is MuJoCo's ``mj_kinematics`` for a tree of hinges under one free joint, with rotation matrices: bodies in
model order (every parent before its children),

    R_b = R_parent R(body_quat_b),   x_b = x_parent + R_parent body_pos_b      (the root: the base pose instead)
    for each hinge j of body b, in order:
        a_j = R_b axis_j,   c_j = x_b + R_b pos_j                              (its axis and anchor)
        R_b <- R_b Rot(axis_j, theta_j),   x_b = c_j - R_b pos_j

A point fixed to body ``b`` at ``l`` (body frame) is at ``p = x_b + R_b l``; its Jacobian column for hinge ``j``
is ``a_j x (p - c_j)`` when ``j`` is on the chain from the root to ``b``, else zero (what ``mj_jac`` gives for
a hinge). ``tests/test_kinematics.py`` checks both against MuJoCo's ``mj_kinematics`` and ``mj_jac``.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numba
import numpy as np

from harness.errors import ModelError


@dataclass(frozen=True)
class KinematicTree:
    """A tree of hinges under one free joint.

    parent ``(B,)``: each body's parent (parents first; body 0 is the world); body_pos ``(B, 3)`` (m) and
    body_rot ``(B, 3, 3)``: each body's frame in its parent's at zero angles; root: the free joint's body;
    joint_body ``(J,)``: each hinge's body, in model order (non-decreasing); joint_pos ``(J, 3)`` (m) and
    joint_axis ``(J, 3)`` (unit): its anchor and axis in its body's frame; chain ``(B, D)``: the hinges that
    move body ``b`` (on the chain from the root to it), the first ``chain_len[b]`` of each row."""

    parent: np.ndarray
    body_pos: np.ndarray
    body_rot: np.ndarray
    root: int
    joint_body: np.ndarray
    joint_pos: np.ndarray
    joint_axis: np.ndarray
    chain: np.ndarray
    chain_len: np.ndarray

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "KinematicTree":
        """The tree of a compiled model whose first joint is a free joint and whose other joints are hinges."""
        if model.njnt < 1 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE or not np.all(
                model.jnt_type[1:] == mujoco.mjtJoint.mjJNT_HINGE):
            raise ModelError("a kinematic tree needs one free joint first and hinges after it")
        parent = model.body_parentid.astype(np.int64)
        joint_body = model.jnt_bodyid[1:].astype(np.int64)
        if np.any(parent[1:] >= np.arange(1, model.nbody)) or np.any(np.diff(joint_body) < 0):
            raise ModelError("bodies must follow their parents and hinges their bodies (MuJoCo's order)")
        body_rot = np.empty((model.nbody, 9))
        for b in range(model.nbody):
            mujoco.mju_quat2Mat(body_rot[b], model.body_quat[b])
        chains = []
        for b in range(model.nbody):
            path = []
            while b > 0:
                path.append(b)
                b = parent[b]
            chains.append([j for j in range(len(joint_body)) if joint_body[j] in path])
        chain = np.full((model.nbody, max(map(len, chains))), -1, dtype=np.int64)
        for b, joints in enumerate(chains):
            chain[b, :len(joints)] = joints
        return cls(parent, model.body_pos.copy(), body_rot.reshape(-1, 3, 3), int(model.jnt_bodyid[0]), joint_body,
                   model.jnt_pos[1:].copy(), model.jnt_axis[1:].copy(), chain,
                   np.array([len(c) for c in chains], dtype=np.int64))

    @property
    def arrays(self) -> tuple:
        """The tree as the kernels take it (one argument)."""
        return (self.parent, self.body_pos, self.body_rot, self.root, self.joint_body, self.joint_pos,
                self.joint_axis, self.chain, self.chain_len)

    @property
    def n_joints(self) -> int:
        return len(self.joint_body)


def points_and_jacobians(tree: KinematicTree, angles: np.ndarray, base_rot: np.ndarray, base_pos: np.ndarray,
                         point_body: np.ndarray, point_local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(T, P, 3)`` and Jacobians ``(T, P, 3, J)`` w.r.t. the hinge angles of body-fixed points, for
    angles ``(T, J)`` and the root placed at ``base_rot (T, 3, 3)``, ``base_pos (T, 3)``."""
    angles = np.ascontiguousarray(angles, dtype=float)
    T, P = len(angles), len(point_body)
    pos, jac = np.empty((T, P, 3)), np.empty((T, P, 3, tree.n_joints))
    _batch(tree.arrays, angles, np.ascontiguousarray(base_rot, dtype=float),
           np.ascontiguousarray(base_pos, dtype=float), np.ascontiguousarray(point_body, dtype=np.int64),
           np.ascontiguousarray(point_local, dtype=float), pos, jac)
    return pos, jac


@numba.njit(cache=True)
def _batch(tree, angles, base_rot, base_pos, point_body, point_local, pos, jac):
    frames = frame_work(tree)
    for t in range(len(angles)):
        body_frames_into(tree, angles[t], base_rot[t], base_pos[t], frames)
        points_and_jacobians_into(tree, frames, point_body, point_local, pos[t], jac[t])


@numba.njit(cache=True)
def frame_work(tree):
    """Work arrays of ``body_frames_into``: body rotations ``(B, 3, 3)`` and origins ``(B, 3)``, hinge axes and
    anchors ``(J, 3)``."""
    B, J = len(tree[0]), len(tree[4])
    return np.empty((B, 3, 3)), np.empty((B, 3)), np.empty((J, 3)), np.empty((J, 3))


@numba.njit(cache=True)
def body_frames_into(tree, angles, base_rot, base_pos, frames):
    """Every body's rotation and origin and every hinge's axis and anchor (``frames``, ``frame_work``) at
    ``angles`` ``(J,)``, the root at ``base_rot``, ``base_pos`` (the walk of the module docstring). Written on
    scalars: numba's ``@`` on 3 x 3 arrays allocates and calls BLAS, ten times slower here."""
    parent, body_pos, body_rot, root, joint_body, joint_pos, joint_axis = tree[:7]
    R, x, axis, anchor = frames
    hinge, before = np.empty((3, 3)), np.empty((3, 3))
    R[0] = np.eye(3)
    x[0] = 0.0
    j = 0
    for b in range(1, len(parent)):
        if b == root:
            R[b] = base_rot
            x[b] = base_pos
        else:
            p = parent[b]
            _rotate_into(R[p], body_rot[b], R[b])
            for r in range(3):
                x[b, r] = x[p, r] + R[p, r, 0] * body_pos[b, 0] + R[p, r, 1] * body_pos[b, 1] + R[p, r, 2] * body_pos[b, 2]
        while j < len(joint_body) and joint_body[j] == b:
            a, c = joint_axis[j], joint_pos[j]
            for r in range(3):
                axis[j, r] = R[b, r, 0] * a[0] + R[b, r, 1] * a[1] + R[b, r, 2] * a[2]
                anchor[j, r] = x[b, r] + R[b, r, 0] * c[0] + R[b, r, 1] * c[1] + R[b, r, 2] * c[2]
            _axis_rotation(a, angles[j], hinge)
            before[:] = R[b]
            _rotate_into(before, hinge, R[b])
            for r in range(3):
                x[b, r] = anchor[j, r] - R[b, r, 0] * c[0] - R[b, r, 1] * c[1] - R[b, r, 2] * c[2]
            j += 1


@numba.njit(cache=True)
def _rotate_into(A, B, out):
    """``out = A B`` for 3 x 3 matrices (``out`` not ``A`` or ``B``)."""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c]


@numba.njit(cache=True)
def _axis_rotation(a, theta, out):
    """``out = Rot(a, theta) = I + sin(theta) [a]_x + (1 - cos(theta)) [a]_x^2`` for a unit axis (Rodrigues)."""
    s, c = np.sin(theta), 1.0 - np.cos(theta)
    out[0, 0] = 1.0 - c * (a[1] * a[1] + a[2] * a[2])
    out[1, 1] = 1.0 - c * (a[0] * a[0] + a[2] * a[2])
    out[2, 2] = 1.0 - c * (a[0] * a[0] + a[1] * a[1])
    out[0, 1], out[1, 0] = c * a[0] * a[1] - s * a[2], c * a[0] * a[1] + s * a[2]
    out[0, 2], out[2, 0] = c * a[0] * a[2] + s * a[1], c * a[0] * a[2] - s * a[1]
    out[1, 2], out[2, 1] = c * a[1] * a[2] - s * a[0], c * a[1] * a[2] + s * a[0]


@numba.njit(cache=True)
def points_into(frames, point_body, point_local, pos):
    """Positions ``pos`` ``(P, 3)`` of body-fixed points at the body frames ``frames``."""
    R, x = frames[0], frames[1]
    for i in range(len(point_body)):
        b = point_body[i]
        for r in range(3):
            pos[i, r] = x[b, r] + R[b, r, 0] * point_local[i, 0] + R[b, r, 1] * point_local[i, 1] \
                + R[b, r, 2] * point_local[i, 2]


@numba.njit(cache=True)
def points_and_jacobians_into(tree, frames, point_body, point_local, pos, jac):
    """Positions ``pos`` ``(P, 3)`` and Jacobians ``jac`` ``(P, 3, J)`` of body-fixed points at the body frames
    ``frames``: column ``j`` is ``a_j x (p - c_j)`` on the point's chain, zero elsewhere."""
    chain, chain_len = tree[7], tree[8]
    axis, anchor = frames[2], frames[3]
    points_into(frames, point_body, point_local, pos)
    jac[:] = 0.0
    for i in range(len(point_body)):
        b = point_body[i]
        for k in range(chain_len[b]):
            j = chain[b, k]
            d0, d1, d2 = pos[i, 0] - anchor[j, 0], pos[i, 1] - anchor[j, 1], pos[i, 2] - anchor[j, 2]
            jac[i, 0, j] = axis[j, 1] * d2 - axis[j, 2] * d1
            jac[i, 1, j] = axis[j, 2] * d0 - axis[j, 0] * d2
            jac[i, 2, j] = axis[j, 0] * d1 - axis[j, 1] * d0
