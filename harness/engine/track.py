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

import copy
from collections import deque
from dataclasses import dataclass

import numpy as np

from harness import geometry
from harness.engine.config import BeliefSettings, MotionSettings, ReinjectionSettings, TracksSettings
from harness.engine.database import MotionDatabase
from harness.engine.frame import Frame
from harness.engine.particle_filter import ParticleCloud, ProcessNoise, level_world, motion_mean, propose
from harness.engine.recognition import Recognizer
from harness.engine.records import TrackRecord
from harness.engine.recovery import Recovery
from harness.engine.switching import SwitchingRecognizer
from harness.engine.transform import PointDistributions

# Depth reflection in the camera frame (through the plane z = const) and the body's left/right mirror in the
# base frame (y -> -y). Their composition maps a pose to its twin: X = R x + t and S (X - t) + t = (S R S_b)
# (S_b x) + t, where S_b x is the mirrored body. A reflection through the plane normal to a unit ``a`` is minus
# the half turn about ``a``, so S R S_b is the rotation H_a R H_y (the two signs cancel): as quaternions,
# (0, a) q (0, e_y), a signed permutation and sum of q's components, exact (``twin``).
_DEPTH_NORMAL = np.array([0.0, 0.0, 1.0])
_HALF_TURN_Y = np.array([0.0, 0.0, 1.0, 0.0])


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
    normal = _DEPTH_NORMAL if gravity is None else level_world(gravity)[0]     # the reflection's plane normal
    q = geometry.multiply(geometry.multiply(np.concatenate([[0.0], normal]), quats), _HALF_TURN_Y)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


@dataclass(frozen=True)
class Alternative:
    """A transform of a track's poses, re-injection's alternative to its path: a turn (rad) about the body's
    vertical, then optionally the twin, then a depth scale (positions scaled about the camera centre, which
    keeps the body where the flows are in the image)."""

    name: str
    turn: float = 0.0
    twin: bool = False
    depth: float = 1.0

    def apply(self, positions: np.ndarray, quats: np.ndarray, gravity: np.ndarray | None
              ) -> tuple[np.ndarray, np.ndarray]:
        """Poses ``(N, 3)``, ``(N, 4)`` transformed."""
        q = turned(quats, self.turn) if self.turn else quats
        q = twin(q, gravity) if self.twin else q
        return positions * self.depth, q


def alternatives(settings: ReinjectionSettings) -> list[Alternative]:
    """Re-injection's alternatives to a track's path: its turns, the twin, its depth scales."""
    out = [Alternative(f"turn{a:+g}", turn=np.deg2rad(a)) for a in settings.turns]
    if settings.twin:
        out.append(Alternative("twin", twin=True))
    out += [Alternative(f"depth{d:g}", depth=d) for d in settings.depths]
    return out


def new_recognizer(db: MotionDatabase, belief: BeliefSettings) -> Recognizer:
    """A track's belief over (primitive, state): the isolated recursion, or the switching one for streams."""
    if belief.primitive_switch > 0:
        return SwitchingRecognizer(db, belief.primitive_switch, belief.start_spread, belief.stream_prune)
    return Recognizer(db, belief.start_spread, belief.prune)


@dataclass(frozen=True)
class Snapshot:
    """A track at the end of one frame, as re-injection replays it: the frame's index (None: before the
    track's first frame), the pose recognition was evaluated at (None before the first frame), the belief
    after the frame (a copy of the recognizer) and the evidence so far."""

    index: int | None
    pose: tuple[np.ndarray, np.ndarray] | None
    recognizer: Recognizer
    log_evidence: float


class Track:
    """One global-pose hypothesis (see the module docstring).

    id: unique within a sequence; origin: how it was spawned (``lead``, ``turn+90``, ``turn180``, ``turn-90``,
    ``twin``, ``given``; prefixed ``walk/`` for a track of one primitive); primitive: the one primitive the track
    hypothesises (its belief is restricted to it), or None for a belief over all; recognizer: its belief;
    cloud: its particles (None when the pose is given);
    log_evidence: tempered nats since the first frame with flows; pose: this frame's filter estimate
    ``(position (3,), quaternion (4,))`` and pose_std ``(3,)`` the position std recovery may use around it;
    recovery: what recovery found this frame (the next proposal is guided by it when it was refined);
    history: the last ``memory`` snapshots (``Snapshot``; none when ``memory`` is 0), the first one from before
    the track's first frame until the window passes it; parent: the id of the track it was re-injected from (None: spawned).
    """

    def __init__(self, track_id: int, origin: str, recognizer: Recognizer, cloud: ParticleCloud | None = None, *,
                 primitive: int | None = None, memory: int = 0,
                 log_evidence: float = 0.0, parent: int | None = None):
        self.id = int(track_id)
        self.origin = origin
        self.primitive = primitive
        self.parent = parent
        self.recognizer = recognizer
        self.cloud = cloud
        self.log_evidence = float(log_evidence)
        self.pose: tuple[np.ndarray, np.ndarray] | None = None
        self.pose_std = np.zeros(3)
        self.recovery: Recovery | None = None
        self.history: deque[Snapshot] = deque(maxlen=int(memory))
        if memory:
            self.history.append(Snapshot(None, None, copy.copy(recognizer), self.log_evidence))

    def __repr__(self) -> str:
        return f"Track({self.id}, {self.origin}, evidence {self.log_evidence:.1f})"

    # --- the belief -----------------------------------------------------------------------------

    def predict_belief(self) -> None:
        """Move the belief through the HMM transitions. A state's base velocity is over the interval ending at
        its own frame (``features.VELOCITY_SCHEME``), so the belief moves before it predicts the base."""
        self.recognizer.predict()

    def pose_mixture(self, settings: TracksSettings) -> tuple[np.ndarray, np.ndarray]:
        """What the track's particles are weighed under: log weights ``(k,)`` and the ``k`` terms' state
        weights ``(k, C * K)``, each term to be moment-matched over its states (``PointDistributions.mixtures``).

        A track of one primitive: that primitive's active states, one term. A track that believes several
        primitives (streams): with ``weigh_by_belief``, the belief's most probable primitives
        (``class_mixtures``); else one term in which every primitive counts alike, each with its own belief over
        its states (``every_primitive``), so that a wrong class belief cannot steer the pose."""
        if self.primitive is None and not settings.weigh_by_belief:
            return np.zeros(1), self.every_primitive()
        return self.class_mixtures(settings.weigh_classes, settings.weigh_class_mass)

    def every_primitive(self) -> np.ndarray:
        """``(1, C * K)``: each primitive's belief over its active states (``state_posterior``, rows summing to
        one), the primitives weighed alike (a primitive outside the belief, which is never evaluated, is left
        out)."""
        rows = np.where(self.recognizer.active(), self.recognizer.state_posterior, 0.0)
        mass = rows.sum(axis=1)
        possible = mass > 0
        rows[possible] /= mass[possible, None] * possible.sum()
        return rows.reshape(1, -1)

    def class_mixtures(self, max_classes: int, mass: float) -> tuple[np.ndarray, np.ndarray]:
        """The belief as a mixture over its most probable primitives (at most ``max_classes``, fewest covering
        ``mass`` of the class posterior), each primitive to be moment-matched over its active states
        (``PointDistributions.mixtures``): log weights ``(k,)`` (renormalised over the kept primitives) and the
        ``k`` terms' state weights ``(k, C * K)``.

        One moment-matched blob over every primitive is so wide early on that the particles cannot tell depth;
        a term per primitive keeps the shape of each."""
        rec = self.recognizer
        if self.primitive is not None:          # a belief in one primitive: one term (the general path's answer)
            rows = np.zeros(rec.log_alpha.shape)
            p = self.primitive
            rows[p] = np.where(rec.active()[p], rec.posterior[p], 0.0)
            return np.zeros(1), rows.reshape(1, -1)
        joint = np.where(rec.active(), rec.posterior, 0.0)
        post = rec.class_posterior
        order = np.argsort(post)[::-1]
        k = min(max_classes, int(np.searchsorted(np.cumsum(post[order]), mass)) + 1)
        keep = order[:k]
        C, K = joint.shape
        rows = np.zeros((k, C, K))
        rows[np.arange(k), keep] = joint[keep]
        w = post[keep] / post[keep].sum()
        return np.log(w), rows.reshape(k, C * K)

    def base_velocity(self, dists: PointDistributions) -> tuple[np.ndarray, np.ndarray]:
        """The base velocity the belief predicts (base frame): linear (m/s) and angular (rad/s)."""
        post = self.recognizer.posterior.ravel()
        return post @ dists.base_linear, post @ dists.base_angular

    def best_states(self) -> tuple[int, np.ndarray]:
        """The most probable primitive and its state belief ``(K,)`` (recovery's prior)."""
        best = int(np.argmax(self.recognizer.class_posterior))
        return best, self.recognizer.state_posterior[best]

    def best_state_belief(self) -> np.ndarray:
        """``(C * K,)``: ``best_states`` placed among all database states, zero elsewhere."""
        C, K = self.recognizer.log_alpha.shape
        best, states = self.best_states()
        out = np.zeros(C * K)
        out[best * K:(best + 1) * K] = states
        return out

    # --- the pose -------------------------------------------------------------------------------

    def guided(self, motion: MotionSettings) -> bool:
        """Whether the next proposal is guided by this frame's recovery (it refined the track's pose)."""
        return self.recovery is not None and self.recovery.refined and motion.guide_fraction > 0

    def move(self, frame: Frame, dists: PointDistributions, n: int, noise: ProcessNoise,
             rng: np.random.Generator, motion: MotionSettings, *, recovered_quat: np.ndarray) -> None:
        """Propose ``n`` particles for this frame: the motion model at the belief's base velocity, mixed with
        proposals around last frame's recovered pose when recovery refined it (``particle_filter.propose``;
        ``recovered_quat``: its rotation as a quaternion, ``geometry.from_matrix``, which the caller finds for
        all guided tracks at once)."""
        v, w = self.base_velocity(dists)
        guide = guide_std = None
        rec = self.recovery
        if self.guided(motion):
            g_pos, g_quat = motion_mean(rec.position[None], recovered_quat[None], v, w, frame.dt, frame.camera_motion)
            guide = (g_pos[0], g_quat[0])
            guide_std = (0.5 * self.pose_std, motion.guide_rotation_std)
        self.cloud = propose(self.cloud, n, noise, rng, base_linear=v, base_angular=w, dt=frame.dt,
                             camera_motion=frame.camera_motion, guide=guide, guide_fraction=motion.guide_fraction,
                             guide_std=guide_std)

    def settle(self, position: np.ndarray, quat: np.ndarray, spread: np.ndarray, min_std: float) -> None:
        """This frame's pose: the cloud's estimate (``particle_filter.settled``), with its spread (at least
        ``min_std``) as recovery's room."""
        self.pose = (position, quat)
        self.pose_std = np.maximum(spread, min_std)

    def place(self, position: np.ndarray, quat: np.ndarray) -> None:
        """This frame's pose, given (no room for recovery to move it)."""
        self.pose = (np.asarray(position, dtype=float), np.asarray(quat, dtype=float))
        self.pose_std = np.zeros(3)

    def recovered(self, recovery: Recovery) -> None:
        self.recovery = recovery

    def remember(self, index: int, pose: tuple[np.ndarray, np.ndarray]) -> None:
        """Keep this frame's snapshot (after recognition at ``pose``): what re-injection replays from (nothing
        when the track keeps no history)."""
        if self.history.maxlen:
            self.history.append(Snapshot(index, pose, copy.copy(self.recognizer), self.log_evidence))

    def record(self) -> TrackRecord:
        """What the track is at the end of this frame."""
        return TrackRecord(self.id, self.origin, self.log_evidence, self.pose[0], self.pose[1], self.recovery.qpos,
                           self.recognizer.posterior)


def prune_and_merge(tracks: list[Track], prune_nats: float, merge_m: float, merge_deg: float) -> list[Track]:
    """The tracks worth keeping, most evidence first: those within ``prune_nats`` of the best, and of two that met
    (positions within ``merge_m``, orientations within ``merge_deg``) and hypothesise the same primitive (or both
    any) only the one with more evidence: a primitive's own best pose is kept until the evidence drops it."""
    best = max(t.log_evidence for t in tracks)
    kept = sorted((t for t in tracks if t.log_evidence >= best - prune_nats), key=lambda t: -t.log_evidence)
    # Which pairs met, all at once (a track a pair of scalars each was a tenth of a late frame's Python).
    pos = np.array([t.pose[0] for t in kept])
    quat = np.array([t.pose[1] for t in kept])
    J = len(kept)
    met = ((np.linalg.norm(pos[:, None] - pos[None], axis=-1) < merge_m)
           & (geometry.angle_between(np.broadcast_to(quat[:, None], (J, J, 4)), np.broadcast_to(quat[None], (J, J, 4)))
              < np.deg2rad(merge_deg)))
    merged: list[int] = []
    for i, track in enumerate(kept):
        if not any(met[i, j] and kept[j].primitive == track.primitive for j in merged):
            merged.append(i)
    return [kept[i] for i in merged]
