"""A pose track: one hypothesis about the demonstrator's global pose, with everything that depends on it.

Unlabeled points seen nearly orthographically have an exact twin (depth reflected through the pelvis plane,
the body mirrored), and stationary primitives look alike under quarter turns until their distinctive phase.
So the engine keeps several tracks. Each owns a particle cloud over the baselink pose, its own belief over
primitives and states (a forward recursion whose emissions are evaluated at the track's pose), the angles
recovery found for it, and its evidence

    log p(y_1:t | track) = sum_s log sum_ck alpha_s|s-1(c, k) b_s(c, k)

the sum of its recursion's normalisers (classes and states summed out, with the engine's tempering and
pruning). Tracks are compared by evidence; the decision between them is made as late as the evidence allows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness import geometry
from harness.engine.particle_filter import ParticleCloud, level_world
from harness.engine.recognition import Recognizer
from harness.engine.transform import PointDistributions

# Depth reflection in the camera frame (through the plane z = const) and the body's left/right mirror in the
# base frame (y -> -y). Their composition maps a pose to its twin: X = R x + t and S (X - t) + t = (S R S_b)
# (S_b x) + t, where S_b x is the mirrored body.
_DEPTH_REFLECTION = np.diag([1.0, 1.0, -1.0])
_BODY_MIRROR = np.diag([1.0, -1.0, 1.0])


def turned(quats: np.ndarray, angle: float) -> np.ndarray:
    """Orientations ``(N, 4)`` turned by ``angle`` (rad) about the body's own vertical axis."""
    return geometry.multiply(quats, geometry.yaw(np.full(len(quats), angle)))


def twin(quats: np.ndarray, gravity: np.ndarray | None = None) -> np.ndarray:
    """The twins of orientations ``(N, 4)`` (camera from base).

    Without gravity: the depth-reflected, mirrored twins ``S R S_b`` (see the module docstring), exact under
    orthographic projection; they also reflect the camera's pitch. With gravity (a unit vector in the camera
    frame) the twin stays upright: the reflection is through the vertical plane across the camera's
    horizontal viewing direction, ``W^T diag(-1, 1, 1) W R S_b`` with ``W`` the level world of
    ``particle_filter.level_world``.
    """
    rot = geometry.to_matrix(quats)
    if gravity is None:
        return geometry.from_matrix(_DEPTH_REFLECTION @ rot @ _BODY_MIRROR)
    world = level_world(gravity)
    return geometry.from_matrix(world.T @ np.diag([-1.0, 1.0, 1.0]) @ world @ rot @ _BODY_MIRROR)


@dataclass
class Recovered:
    """What recovery found for a track in the current frame: angles ``(50,)``, base position ``(3,)`` and
    rotation ``(3, 3)`` in the camera frame; refined: whether the flows refined them (else the belief's mean
    angles at the filter's estimate)."""

    angles: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    refined: bool = True


class Track:
    """One global-pose hypothesis (see the module docstring).

    cloud: its particles (None when the pose is given); recognizer: its belief; origin: how it was spawned
    (``lead``, ``turn+90``, ``turn180``, ``turn-90``, ``twin``, ``given``); log_evidence: tempered nats since
    the first frame with flows; estimate: this frame's filter estimate ``(position, quaternion)``;
    recovered: this frame's recovery; history: its configurations so far (for the offline estimate).
    """

    def __init__(self, cloud: ParticleCloud | None, recognizer: Recognizer, origin: str, log_evidence: float = 0.0):
        self.cloud = cloud
        self.recognizer = recognizer
        self.origin = origin
        self.log_evidence = float(log_evidence)
        self.estimate: tuple[np.ndarray, np.ndarray] | None = None
        self.recovered: Recovered | None = None
        self.spread = np.zeros(3)
        self.history: list[np.ndarray] = []     # its recovered configuration (57,) at every frame since it started

    def __repr__(self) -> str:
        return f"Track({self.origin}, evidence {self.log_evidence:.1f})"

    def class_mixtures(self, dists: PointDistributions, max_classes: int, mass: float
                       ) -> tuple[np.ndarray, PointDistributions]:
        """The belief as a mixture over its most probable primitives (at most ``max_classes``, fewest covering
        ``mass`` of the class posterior), each primitive moment-matched over its active states: log weights
        ``(k,)`` (renormalised over the kept primitives) and ``k`` one-state point distributions.

        One moment-matched blob over every primitive is so wide early on that the particles cannot tell depth;
        a term per primitive keeps the shape of each."""
        post = self.recognizer.class_posterior
        order = np.argsort(post)[::-1]
        k = min(max_classes, int(np.searchsorted(np.cumsum(post[order]), mass)) + 1)
        keep = order[:k]
        active = self.recognizer.active()
        joint = self.recognizer.posterior
        K = joint.shape[1]
        parts = [dists.take(c * K + np.flatnonzero(active[c])).mixture(joint[c][active[c]]) for c in keep]
        w = post[keep] / post[keep].sum()
        return np.log(w), PointDistributions.concatenate(parts)

    def base_velocity(self, dists: PointDistributions) -> tuple[np.ndarray, np.ndarray]:
        """The base velocity the belief predicts (base frame): linear (m/s) and angular (rad/s)."""
        post = self.recognizer.posterior.ravel()
        return post @ dists.base_linear, post @ dists.base_angular

    def best_state_belief(self) -> np.ndarray:
        """``(C * K,)``: the state belief of the most probable primitive, zero elsewhere (recovery's prior)."""
        C, K = self.recognizer.log_alpha.shape
        best = int(np.argmax(self.recognizer.class_posterior))
        out = np.zeros(C * K)
        out[best * K:(best + 1) * K] = self.recognizer.state_posterior[best]
        return out
