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

import numpy as np

from harness import geometry
from harness.body.kinematics import forward_points_and_jacobians
from harness.body.model import BodyModel
from harness.body.surface import SurfacePoints
from harness.engine.features import ANGLE_RATES, ANGLES
from harness.engine.likelihood import FlowModel, responsibilities
from harness.engine.transform import MIN_DEPTH, JointGaussians, _skew, state_point_distributions, to_image
from harness.pinhole import Intrinsics, project, projection_jacobian

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
        """``(57,)``: base position, base quaternion (camera from base), angles."""
        return np.concatenate([self.position, geometry.from_matrix(self.rotation), self.angles])


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
    pos = np.asarray(start.position, dtype=float).copy()
    rot = np.asarray(start.rotation, dtype=float).copy()
    flows = np.asarray(flows, dtype=float).reshape(-1, 4)
    mass = resp.sum(axis=0)                                          # (P,)
    used = mass > 1e-3
    if len(flows) == 0 or not used.any() or iterations <= 0:
        return Recovery(angles, pos, rot)
    target = (resp[:, used].T @ flows[:, :2]) / mass[used, None]      # (P_used, 2)
    sub = points.subset(np.flatnonzero(used))
    prior_prec = np.concatenate([1.0 / np.asarray(prior.angle_std) ** 2, 1.0 / np.asarray(prior.position_std) ** 2,
                                 np.full(3, 1.0 / prior.rotation_std**2)])
    qpos = np.zeros(57)
    qpos[3] = 1.0
    for _ in range(iterations):
        qpos[7:] = angles
        x, jac = forward_points_and_jacobians(body, qpos, sub.body, sub.local, frame="base")
        X = x @ rot.T + pos
        if np.any(X[:, 2] < MIN_DEPTH):
            break
        u = project(intr, X)
        P = projection_jacobian(intr, X)                              # (Q, 2, 3)
        sigma2 = noise_px**2 + (intr.fy * spread / X[:, 2]) ** 2
        w = mass[used] / sigma2                                       # (Q,)
        PR = P @ rot
        G = np.concatenate([PR @ jac, P, -PR @ _skew(x)], axis=2)     # (Q, 2, 56)
        Gw = (G * np.sqrt(w)[:, None, None]).reshape(-1, G.shape[-1])     # rows of sqrt(W_p) G_p
        A = Gw.T @ Gw                                                    # sum_p W_p G_p^T G_p
        b = Gw.T @ ((target - u) * np.sqrt(w)[:, None]).ravel()          # sum_p W_p G_p^T r_p
        offset = np.concatenate([angles - prior.angles, pos - prior.position,
                                 geometry.log(geometry.from_matrix(prior.rotation.T @ rot))])
        A[np.diag_indices_from(A)] += prior_prec
        b -= prior_prec * offset
        A[np.diag_indices_from(A)] *= 1.0 + damping
        step = np.zeros(56)
        free = slice(0, 50) if fix_pose else slice(0, 56)
        step[free] = np.linalg.solve(A[free, free], b[free])
        angles = np.clip(angles + step[:50], body.lower, body.upper)
        pos = pos + step[50:53]
        rot = rot @ geometry.to_matrix(geometry.exp(step[53:]))
    return Recovery(angles, pos, rot)


def recover(scorer: "Scorer", frame: "Frame", state_belief: np.ndarray, position: np.ndarray, rot: np.ndarray,
            position_std: np.ndarray, *, refine: bool = True, fix_pose: bool = False) -> Recovery:
    """Angles of a recognised primitive and a refined pose, by EM against the frame's flows.

    ``state_belief`` ``(S,)`` over all database states (zero outside the recognised primitive). The prior is
    the belief's moment-matched Gaussian over the angles; the pose prior is ``position`` ``(3,)``,
    ``rot`` ``(3, 3)`` with ``position_std`` ``(3,)`` and the setting ``refine_rotation_std``. The E-step
    assigns flows to model points softly, first under the state belief, then at the current estimate (whose
    points only spread over their surface patch), with the likelihood's visibility and weights; the M-step is
    ``refine_pose``. Without flows, or with ``refine`` false, the prior mean at the given pose.
    """
    model, config = scorer.model, scorer.config
    idx = np.flatnonzero(state_belief > 0)
    gamma = state_belief[idx] / state_belief[idx].sum()
    means, covars = model.db_means[idx], model.db_covars[idx]
    theta0 = gamma @ means[:, ANGLES]
    var = gamma @ (covars[:, ANGLES] + (means[:, ANGLES] - theta0) ** 2)
    rates = gamma @ means[:, ANGLE_RATES]
    rate_var = gamma @ (covars[:, ANGLE_RATES] + (means[:, ANGLE_RATES] - rates) ** 2)
    current = Recovery(theta0, position, rot, refined=refine)
    if not refine or not frame.has_flows:
        return current
    prior = Prior(theta0, np.sqrt(var), position, position_std, rot, config.refine_rotation_std)
    mix = model.dists.mixture(state_belief)
    for it in range(config.em_iterations):
        if it:
            mix = state_point_distributions(model.body, JointGaussians.at(current.angles, rates, rate_var,
                                                                          mix.base_linear[0], mix.base_angular[0]),
                                            model.points, model.spread)
        img = scorer.image(frame, current.rotation[None], current.position[None], mix)
        resp = scorer.responsibilities(frame, img)
        current = refine_pose(model.body, model.points, frame.intr, frame.flows, resp, prior,
                              noise_px=config.noise_px, spread=model.spread, iterations=config.refine_iterations,
                              start=current, fix_pose=fix_pose)
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
    flow_model = FlowModel(noise_px, 1.0, intr.width, intr.height)
    for t, f in enumerate(flows):
        rot = geometry.to_matrix(base_quat[t])
        for _ in range(iterations if len(f) else 0):
            dist = state_point_distributions(body, JointGaussians.at(angles), points, spread)
            img = to_image(intr, rot[None], base_pos[t][None], dist)
            # Positions only: a velocity covariance this wide makes the velocity factor constant.
            img = type(img)(img.pix, img.pix_cov, img.flow, np.broadcast_to(1e12 * np.eye(2), img.flow_cov.shape),
                            img.visibility)
            resp = responsibilities(f, img, flow_model)
            prior = Prior(angles, np.full(50, angle_step_std), base_pos[t], np.full(3, 1e-4), rot, 1e-4)
            angles = refine_pose(body, points, intr, f, resp, prior, noise_px=noise_px, spread=spread,
                                 iterations=1).angles
        out[t] = angles
    return out
