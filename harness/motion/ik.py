"""Inverse kinematics of humanoid56 onto body-point targets over a clip: the retargeting's solver.

Per frame, with ``x_k(q)`` the body points and ``g_k`` their targets (metres, world), the solver minimises

    C(q) = sum_k w_k^2 |g_k - x_k(q)|^2 + posture^2 |theta|^2

over the base pose (position, and rotation increments in the world frame) and the 50 angles ``theta``
inside their ranges. The posture term pulls the angles towards the zero pose, so that combinations joint
positions cannot see (a spine twist undone by the clavicles, a humerus twist with a straight elbow) stay put.

**Bounded Levenberg-Marquardt.** A step solves ``(J^T J + P + lambda^2 I) dq = J^T r - P theta`` (``P`` the
posture term) over the free unknowns; an angle at a bound whose gradient points outwards is held there
(an active set), so that a limb pressed against one limit still moves in its other joints. A step is kept
only if it lowers ``C`` (``lambda`` shrinks), otherwise ``lambda`` grows and the step is tried again.
Projected damped least squares without the active set and the acceptance test stalled on the joint
limits for whole stretches of a clip (frames 20-94 cm off in 35 of the 65 sample rows; docs/captures.md).

**Continuation.** Frame t starts from the solution of frame t - 1.

**Restarts.** Continuation follows whatever branch it is on. After a large jump between frames, or where
the arm passes the shoulder's Euler singularity (humerus y, x, z: the arm straight out to the side, which
jumping jacks and throws cross), it can be left in a local minimum: an elbow bent where the source's is
straight, an arm folded behind the head. So when a frame's largest residual exceeds ``RESTART_RESIDUAL`` or
jumps by more than ``RESTART_JUMP`` over the previous frame's, the frame is solved again from seeds and the
lowest ``C`` wins: each limb (shoulder or hip with its elbow or knee) set analytically from its targets, in
each of the two Euler branches of its 3-hinge joint (``limb_branches``: the flips of the shoulder or hip
solution), and the zero pose. A residual that no restart improves is the data's (a source bone that no
human pose follows); later frames restart only when they get worse than it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from harness import geometry
from harness.body import BodyModel, body_frames, forward_points, forward_points_and_jacobians
from harness.body.model import N_ANGLES, NQ, NV

#: Damping (metres): the smallest ``lambda``; small enough to converge to sub-millimetre residuals.
DEFAULT_DAMPING = 0.01
#: Pull of every angle towards zero (the upright reference pose), metres per radian.
DEFAULT_POSTURE = 0.02
#: Most iterations of a continued frame, of the first frame (from the zero pose), of a restart.
DEFAULT_ITERATIONS = 20
FIRST_FRAME_ITERATIONS = 150
RESTART_ITERATIONS = 40
#: A frame is restarted when its largest target residual exceeds this (metres) ...
RESTART_RESIDUAL = 0.05
#: ... or exceeds the previous frame's largest residual by more than this (metres).
RESTART_JUMP = 0.02
#: Stop when no unknown moves more than this (metres or radians) ...
STEP_TOLERANCE = 1e-6
#: ... or a step lowers the cost by less than this fraction.
COST_TOLERANCE = 1e-9
MAX_DAMPING = 1e3
#: Limbs seeded analytically: the 3-hinge body (y, x, z), its 1-hinge child (y), and the child's child.
LIMBS = (("lhumerus", "lradius", "lwrist"), ("rhumerus", "rradius", "rwrist"),
         ("lfemur", "ltibia", "lfoot"), ("rfemur", "rtibia", "rfoot"))


@dataclass(frozen=True)
class _Points:
    """The body points being solved for: body ids ``(K,)``, points in their frames ``(K, 3)``, weights per
    coordinate ``(3K,)``, the posture weight."""

    bodies: np.ndarray
    local: np.ndarray
    w3: np.ndarray
    posture: float


def _skew_columns(r: np.ndarray) -> np.ndarray:
    """``(K, 3, 3)``: column k is ``e_k x r``, the point velocity for a unit world rotation rate about axis k."""
    return -np.cross(r[:, :, None], np.eye(3)[None, :, :], axisa=1, axisb=1, axisc=1)


def _cost(body: BodyModel, pts: _Points, q: np.ndarray, pos: np.ndarray, goal: np.ndarray) -> float:
    r = (goal - pos).ravel() * pts.w3
    theta = q[body.angle_qpos_index]
    return float(r @ r + pts.posture ** 2 * theta @ theta)


def _apply(body: BodyModel, q: np.ndarray, step: np.ndarray) -> np.ndarray:
    out = q.copy()
    out[:3] += step[:3]
    out[3:7] = geometry.normalize(geometry.multiply(geometry.exp(step[3:6]), q[3:7]))
    out[body.angle_qpos_index] = body.clip_angles(q[body.angle_qpos_index] + step[6:])
    return out


def refine(body: BodyModel, pts: _Points, q: np.ndarray, goal: np.ndarray, iterations: int,
           damping: float = DEFAULT_DAMPING) -> tuple[np.ndarray, float]:
    """Bounded Levenberg-Marquardt from ``q`` ``(57,)`` towards ``goal`` ``(K, 3)``; returns the solution and
    its cost ``C`` (module docstring)."""
    q = np.array(q, dtype=float)
    lam = damping
    pos, jac = forward_points_and_jacobians(body, q, pts.bodies, pts.local, frame="world")
    cost = _cost(body, pts, q, pos, goal)
    lo, hi = body.lower, body.upper
    for _ in range(iterations):
        r = (goal - pos).ravel() * pts.w3
        full = np.concatenate([np.broadcast_to(np.eye(3), (len(pos), 3, 3)), _skew_columns(pos - q[:3]), jac],
                              axis=2).reshape(-1, NV) * pts.w3[:, None]
        theta = q[body.angle_qpos_index]
        rhs = full.T @ r
        rhs[6:] -= pts.posture ** 2 * theta
        normal = full.T @ full
        normal[6:, 6:] += pts.posture ** 2 * np.eye(N_ANGLES)
        free = np.ones(NV, dtype=bool)
        free[6:] = ~(((theta <= lo) & (rhs[6:] < 0.0)) | ((theta >= hi) & (rhs[6:] > 0.0)))
        sub = normal[np.ix_(free, free)]
        while True:
            step = np.zeros(NV)
            step[free] = np.linalg.solve(sub + lam ** 2 * np.eye(len(sub)), rhs[free])
            q_new = _apply(body, q, step)
            pos_new, jac_new = forward_points_and_jacobians(body, q_new, pts.bodies, pts.local, frame="world")
            cost_new = _cost(body, pts, q_new, pos_new, goal)
            if cost_new < cost or lam > MAX_DAMPING:
                break
            lam *= 4.0
        if cost_new >= cost:
            break
        gain = cost - cost_new
        q, pos, jac, cost = q_new, pos_new, jac_new, cost_new
        lam = max(lam / 4.0, damping)
        if np.max(np.abs(step)) < STEP_TOLERANCE or gain < COST_TOLERANCE * cost:
            break
    return q, cost


def _wrap(angle: float) -> float:
    return float(np.mod(angle + np.pi, 2.0 * np.pi) - np.pi)


def limb_branches(body: BodyModel, q: np.ndarray, limb: tuple[str, str, str], mid: np.ndarray, end: np.ndarray
                  ) -> list[np.ndarray]:
    """Angles of one limb that put its middle joint on ``mid`` and its end on ``end`` (world, metres) with
    the rest of ``q`` kept: one candidate ``(57,)`` per Euler branch of the 3-hinge joint.

    The limb ``(upper, lower, end body)``: ``upper`` has hinges y, x, z (in that order) and ``lower`` a y
    hinge, both segments along -z at the zero pose. With ``d`` the upper segment's direction in the frame
    ``upper`` has at zero angles, ``Ry(a) Rx(b) (0, 0, -1) = (-cos b sin a, sin b, -cos b cos a) = d`` gives
    ``b = asin(d_y)`` or ``pi - asin(d_y)`` and then ``a``; the bend ``f`` between the segments sets the
    lower hinge (its sign is the side its range allows); the twist ``c`` turns the bend's plane onto the
    lower segment's direction, ``Rz(c) Ry(phi) (0, 0, -1)``. A straight limb leaves ``c`` as it was.
    Candidates are not clipped to the joint ranges; those within them come first.
    """
    upper, lower, _ = limb
    iy, ix, iz = (body.angle_index(f"{upper}_{a}") for a in "yxz")
    il = body.angle_index(f"{lower}_y")
    xpos, xmat = body_frames(body, q)
    uid = body.body_id(upper)
    r0 = xmat[int(body.model.body_parentid[uid])]       # the upper body's frame at zero angles
    d_world = mid - xpos[uid]
    e_world = end - mid
    if np.linalg.norm(d_world) < 1e-6 or np.linalg.norm(e_world) < 1e-6:
        return []
    d_world /= np.linalg.norm(d_world)
    e_world /= np.linalg.norm(e_world)
    d = r0.T @ d_world
    bend = float(np.arccos(np.clip(d_world @ e_world, -1.0, 1.0)))
    phi = -bend if abs(body.lower[il]) > abs(body.upper[il]) else bend
    angles = body.angles(q)
    out = []
    b1 = float(np.arcsin(np.clip(d[1], -1.0, 1.0)))
    for b in (b1, _wrap(np.pi - b1)):
        cb = np.cos(b)
        a = float(np.arctan2(-d[0] / cb, -d[2] / cb)) if abs(cb) > 1e-6 else angles[iy]
        c = angles[iz]
        if abs(np.sin(phi)) > 0.1:
            rot = geometry.to_matrix(geometry.multiply(geometry.exp([0.0, a, 0.0]), geometry.exp([b, 0.0, 0.0])))
            v = rot.T @ r0.T @ e_world
            s = np.sign(np.sin(phi))
            c = float(np.arctan2(-s * v[1], -s * v[0]))
        cand = angles.copy()
        cand[[iy, ix, iz, il]] = a, b, c, phi
        out.append(cand)
    violation = [float(np.sum(np.abs(body.clip_angles(c) - c))) for c in out]
    return [body.qpos(out[i], q[:3], q[3:7]) for i in np.argsort(violation, kind="stable")]


def restart_seeds(body: BodyModel, q: np.ndarray, goal: np.ndarray, names: tuple[str, ...]) -> list[np.ndarray]:
    """Seeds ``(57,)`` for a restart from ``q``: every combination of the limbs' Euler branches (limbs whose
    middle and end bodies are among the target ``names``), then the zero pose at ``q``'s base."""
    per_limb = []
    for limb in LIMBS:
        if limb[1] in names and limb[2] in names:
            branches = limb_branches(body, q, limb, goal[names.index(limb[1])], goal[names.index(limb[2])])
            if branches:
                per_limb.append((limb, branches))
    seeds = []
    for choice in itertools.product(*[range(len(b)) for _, b in per_limb]):
        seed = q.copy()
        for (limb, branches), k in zip(per_limb, choice):
            idx = [body.angle_qpos_index[body.angle_index(f"{limb[0]}_{a}")] for a in "yxz"]
            idx.append(body.angle_qpos_index[body.angle_index(f"{limb[1]}_y")])
            seed[idx] = branches[k][idx]
        seed[body.angle_qpos_index] = body.clip_angles(seed[body.angle_qpos_index])
        seeds.append(seed)
    zero = body.zero_qpos()
    zero[:7] = q[:7]
    return seeds + [zero]


def solve_ik(body: BodyModel, targets: np.ndarray, target_bodies: np.ndarray, init: np.ndarray,
             damping: float = DEFAULT_DAMPING, iterations: int = DEFAULT_ITERATIONS,
             first_iterations: int = FIRST_FRAME_ITERATIONS, weights: np.ndarray | None = None,
             posture: float = DEFAULT_POSTURE, target_local: np.ndarray | None = None,
             target_names: tuple[str, ...] | None = None, restarts: bool = True
             ) -> tuple[np.ndarray, np.ndarray]:
    """IK of body-fixed points onto ``targets (T, K, 3)`` (metres, world), frame by frame.

    ``target_bodies`` ``(K,)`` body ids, ``target_local`` ``(K, 3)`` the points in those bodies' frames
    (metres; default: the body origins), ``weights`` ``(K,)`` scale each target's rows; ``init`` ``(57,)``
    the start of the first frame; every later frame starts from the previous solution. ``target_names``
    ``(K,)`` (humanoid body or site names) let the restarts seed the limbs (module docstring); without
    them, or with ``restarts=False``, a restart only tries the zero pose or nothing. Returns qpos
    ``(T, 57)`` and residual distances ``(T, K)`` metres.
    """
    targets = np.asarray(targets, dtype=float)
    bodies = np.asarray(target_bodies, dtype=int)
    w = np.ones(len(bodies)) if weights is None else np.asarray(weights, dtype=float)
    local = np.zeros((len(bodies), 3)) if target_local is None else np.asarray(target_local, dtype=float)
    pts = _Points(bodies, local, np.repeat(w, 3), posture)
    names = tuple(target_names) if target_names is not None else ()
    q = np.array(init, dtype=float)
    qpos = np.empty((len(targets), NQ))
    residual = np.empty(targets.shape[:2])
    previous, floor = np.inf, 0.0
    for t, goal in enumerate(targets):
        q, cost = refine(body, pts, q, goal, first_iterations if t == 0 else iterations, damping)
        worst = _largest_residual(body, pts, q, goal)
        if restarts and (worst > max(RESTART_RESIDUAL, floor + RESTART_JUMP) or worst > previous + RESTART_JUMP):
            for seed in restart_seeds(body, q, goal, names):
                q_new, cost_new = refine(body, pts, seed, goal, RESTART_ITERATIONS, damping)
                if cost_new < cost:
                    q, cost = q_new, cost_new
            restarted = _largest_residual(body, pts, q, goal)
            # A residual no restart improves is the data's (a source bone no human pose follows): later
            # frames restart only when they get worse than it, not on every frame that keeps it.
            floor = restarted if restarted > worst - RESTART_JUMP else 0.0
        residual[t] = _distances(body, pts, q, goal)
        qpos[t] = q
        previous = residual[t].max()
    return qpos, residual


def _distances(body: BodyModel, pts: _Points, q: np.ndarray, goal: np.ndarray) -> np.ndarray:
    return np.linalg.norm(goal - forward_points(body, q, pts.bodies, pts.local, frame="world"), axis=1)


def _largest_residual(body: BodyModel, pts: _Points, q: np.ndarray, goal: np.ndarray) -> float:
    return float(_distances(body, pts, q, goal).max())
