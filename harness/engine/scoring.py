"""Pose hypotheses scored against one frame's flows, with the engine's settings.

``Scorer`` binds the engine's model (database, body, model points) to its settings, so that a stage asks one
question of one frame: project these distributions at these poses (with the body's self-occlusion and the
camera's own motion), score the flows under them (with the open region's held points: negative evidence),
temper a frame's sum, weigh base poses (the tempered sum and the known floor, ``pose_log_likelihood``), or fold
a frame into a recognizer at a pose. ``path_recognition`` is what a track that
followed a given pose path would gather (its evidence, ``path_evidence``, and its class posteriors);
``path_class_evidence`` the same per primitive; ``floor_log_prior`` the camera prior's floor term.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness import geometry
from harness.engine.bottom_up import fuse
from harness.engine.config import BeliefSettings, LikelihoodSettings
from harness.engine.frame import Frame, observation_frames
from harness.engine.likelihood import (FlowModel, flow_log_likelihoods, responsibilities, tempered,
                                       velocity_log_likelihoods)
from harness.engine.model import EngineModel
from harness.engine.recognition import Recognizer
from harness.engine.transform import (ImageDistributions, JointGaussians, PointDistributions,
                                      state_point_distributions, to_image)
from harness.observation import Observation


@dataclass(frozen=True)
class Scorer:
    """The engine's model and its likelihood settings, asked per frame (see the module docstring)."""

    model: EngineModel
    settings: LikelihoodSettings

    @property
    def occlusion(self) -> tuple[float, float] | None:
        """``to_image``'s self-occlusion parameters (footprint radius, depth gap; metres), or None."""
        if not self.settings.self_occlusion:
            return None
        return 2.0 * self.model.spread * self.settings.occlusion_radius, self.settings.occlusion_depth

    def flow_model(self, frame: Frame) -> FlowModel:
        cfg = self.settings
        return FlowModel(cfg.noise_px, frame.fps, frame.intr.width, frame.intr.height, cfg.outlier_prob,
                         weight_iterations=cfg.weight_iterations, smoothing=cfg.weight_smoothing)

    def image(self, frame: Frame, rot: np.ndarray, pos: np.ndarray, dists: PointDistributions,
              state_index: np.ndarray | None = None) -> ImageDistributions:
        """Distributions projected at base poses ``rot (H, 3, 3)``, ``pos (H, 3)`` (pairing as ``to_image``)."""
        return to_image(frame.intr, rot, pos, dists, camera_motion=frame.camera_motion, state_index=state_index,
                        occlusion=self.occlusion)

    def per_flow(self, frame: Frame, img: ImageDistributions) -> np.ndarray:
        """``(H, M)`` log-likelihood of each of the frame's flows under each hypothesis."""
        return flow_log_likelihoods(frame.flows, img, self.flow_model(frame), open_mask=frame.open)

    def recognition_per_flow(self, frame: Frame, img: ImageDistributions, pose_given: bool = False) -> np.ndarray:
        """``(H, M)`` what recognition scores of each flow: its velocity given its position
        (``recognise_velocities``) at a tracked pose; the flow itself (``per_flow``) otherwise, and at a given
        pose, where the positions carry no pose error."""
        if pose_given or not self.settings.recognise_velocities:
            return self.per_flow(frame, img)
        return velocity_log_likelihoods(frame.flows, img, self.flow_model(frame), open_mask=frame.open)

    def frame_log_likelihood(self, frame: Frame, img: ImageDistributions, n_eff: float) -> np.ndarray:
        """``(H,)`` tempered log-likelihood of the frame under each hypothesis (``likelihood.tempered``)."""
        return tempered(self.per_flow(frame, img), n_eff)

    def pose_log_likelihood(self, frame: Frame, quats: np.ndarray, positions: np.ndarray, dists: PointDistributions,
                            state_index: np.ndarray | None = None, *, n_eff: float) -> np.ndarray:
        """``(H,)`` what a base pose hypothesis is weighed by: the frame's tempered log-likelihood at base poses
        ``quats (H, 4)``, ``positions (H, 3)`` under ``dists`` (pairing as ``image``, one pose per hypothesis),
        plus the camera prior's floor term where the camera knows its height (``floor_log_prior``): every
        weighing of poses, the first frame's included, so that a known floor places the body from the start."""
        img = self.image(frame, geometry.to_matrix(quats), positions, dists, state_index)
        ll = self.frame_log_likelihood(frame, img, n_eff)
        if frame.camera_height is None:
            return ll
        return ll + self.floor_log_prior(frame, _hypothesis_points(dists, state_index, len(ll)), quats, positions)

    def posture_distributions(self, state_weights: np.ndarray, postures: list[tuple[np.ndarray, np.ndarray]],
                              weight: float) -> PointDistributions:
        """``J`` point distributions of beliefs fused with postures known independently of the pose: each belief
        ``state_weights[j]`` ``(S,)`` as one joint-space Gaussian (its states' moments, ``db_means``,
        ``db_covars``) times the posture's Gaussian (features ``(106,)`` and std ``(106,)``, the bottom-up
        estimate's, its precision times ``weight``; ``recovery.fuse``), carried to the model points."""
        model = self.model
        w = np.asarray(state_weights, dtype=float)
        w = w / w.sum(axis=1, keepdims=True)
        mean = w @ model.db_means
        var = np.einsum("js,jsd->jd", w, model.db_covars[None] + (model.db_means[None] - mean[:, None]) ** 2)
        other = np.array([f for f, _ in postures])
        other_var = np.array([sd for _, sd in postures]) ** 2
        mean, var = fuse(mean, var, other, other_var, weight)
        return state_point_distributions(model.body, JointGaussians.from_features(mean, var), model.points,
                                         model.spread)

    def responsibilities(self, frame: Frame, img: ImageDistributions) -> np.ndarray:
        """``(M, P)`` soft assignment of the frame's flows to the model points of one hypothesis."""
        return responsibilities(frame.flows, img, self.flow_model(frame), open_mask=frame.open)

    def recognise(self, frame: Frame, recognizers: list[Recognizer], positions: np.ndarray,
                  quats: np.ndarray, pose_given: bool = False) -> np.ndarray:
        """One recognition step for each recognizer at its base pose (camera frame, ``(J, 3)`` and ``(J, 4)``;
        ``pose_given``: known, not tracked, ``recognition_per_flow``): every active state's tempered emission,
        folded into it. All recognizers' states are projected and scored in one kernel call. Returns the
        recursions' normalisers ``(J,)`` (0 for a frame without flows)."""
        if not frame.has_flows:
            return np.array([rec.update(None) for rec in recognizers])
        actives = [np.flatnonzero(rec.active().ravel()) for rec in recognizers]
        owner = np.repeat(np.arange(len(recognizers)), [len(a) for a in actives])
        rot = geometry.to_matrix(np.asarray(quats, dtype=float).reshape(-1, 4))
        img = self.image(frame, rot[owner], np.asarray(positions, dtype=float).reshape(-1, 3)[owner],
                         self.model.dists, np.concatenate(actives))
        ll = tempered(self.recognition_per_flow(frame, img, pose_given), self.settings.n_eff_recognition)
        out = np.empty(len(recognizers))
        at = 0
        for j, (rec, active) in enumerate(zip(recognizers, actives)):
            log_b = np.zeros(rec.log_alpha.size)
            log_b[active] = ll[at:at + len(active)]
            at += len(active)
            out[j] = rec.update(log_b.reshape(rec.log_alpha.shape))
        return out

    def floor_log_prior(self, frame: Frame, points: np.ndarray, quats: np.ndarray,
                        positions: np.ndarray) -> np.ndarray:
        """``(N,)`` the floor term of the camera prior for base poses (0 without a known camera height)."""
        if frame.camera_height is None:
            return np.zeros(len(positions))
        return floor_log_prior(points, quats, positions, -frame.gravity, frame.camera_height, self.settings)


def _hypothesis_points(dists: PointDistributions, state_index: np.ndarray | None, n: int) -> np.ndarray:
    """``(n, P, 3)`` the model points' mean positions (base frame) of each of ``n`` hypotheses paired with the
    states of ``dists`` as ``to_image`` pairs them (one pose per hypothesis)."""
    if state_index is not None:
        return dists.pos[state_index]
    return np.broadcast_to(dists.pos, (n, *dists.pos.shape[1:])) if len(dists.pos) == 1 else dists.pos


def floor_log_prior(points: np.ndarray, quats: np.ndarray, positions: np.ndarray, up: np.ndarray,
                    camera_height: float, settings: LikelihoodSettings) -> np.ndarray:
    """``(N,)`` log prior of base poses from a known floor: the body's lowest point (of its model points'
    means ``points`` ``(N, P, 3)``, base frame) is on the floor, or in flight above it.

    With ``h`` the lowest point's height above the floor (camera height plus the point's camera-frame
    coordinate along ``up``): ``p(h) = (1 - f) N(h; 0, s^2) + f U(h; 0, H)`` for ``h >= 0``, the Gaussian tail
    below, with ``f = floor_flight``, ``s = floor_std``, ``H = floor_flight_height``.
    """
    # The up direction in each base frame first: one einsum over all three operands ran as a naive loop, 0.3 s
    # for the first frame's 3750 hypotheses against 5 ms in two steps.
    up_base = np.einsum("i,nij->nj", up, geometry.to_matrix(quats))
    h = camera_height + np.einsum("npj,nj->np", points, up_base).min(axis=1) + positions @ up
    cfg = settings
    log_ground = np.log1p(-cfg.floor_flight) - 0.5 * (h / cfg.floor_std) ** 2 - np.log(np.sqrt(2 * np.pi) * cfg.floor_std)
    log_flight = np.where((h >= 0) & (h <= cfg.floor_flight_height), np.log(cfg.floor_flight / cfg.floor_flight_height),
                          -np.inf)
    return np.logaddexp(log_ground, log_flight)


def path_recognition(scorer: Scorer, belief: BeliefSettings, obs: Observation, positions: np.ndarray,
                     quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The recognition of a track that followed exactly a given base pose path ``(T, 3)``, ``(T, 4)`` (camera
    frame): its per-frame evidence ``log p(y_t | y_<t, path)`` ``(T,)`` and class posteriors ``(T, C)`` (before
    the first flows, the uniform prior)."""
    rec = Recognizer(scorer.model.db, belief.start_spread, belief.prune)
    evidence = np.zeros(len(obs))
    posteriors = np.empty((len(obs), scorer.model.n_classes))
    for t, gained in _along_path(scorer, obs, positions, quats, [rec]):
        evidence[t] = gained[0]
        posteriors[t] = rec.class_posterior
    return evidence, posteriors


def _along_path(scorer: Scorer, obs: Observation, positions: np.ndarray, quats: np.ndarray,
                recognizers: list[Recognizer]):
    """Yields ``(t, gained)`` for every frame: the recognizers' normalisers ``(J,)`` after folding frame ``t`` in
    at the path's pose (zeros before the first frame with flows, where a track has not started)."""
    J = len(recognizers)
    started = False
    for frame in observation_frames(obs, scorer.settings):
        t = frame.index
        if not (started or frame.has_flows):
            yield t, np.zeros(J)
            continue
        for rec in recognizers:
            rec.predict()       # a no-op before the first update
        started = True
        yield t, scorer.recognise(frame, recognizers, np.repeat(positions[t][None], J, axis=0),
                                  np.repeat(quats[t][None], J, axis=0))


def path_evidence(scorer: Scorer, belief: BeliefSettings, obs: Observation, positions: np.ndarray,
                  quats: np.ndarray) -> np.ndarray:
    """``(T,)`` per-frame evidence ``log p(y_t | y_<t, path)`` of a given base pose path (``path_recognition``):
    what a track that followed exactly this path would accumulate."""
    return path_recognition(scorer, belief, obs, positions, quats)[0]


def path_class_evidence(scorer: Scorer, belief: BeliefSettings, obs: Observation, positions: np.ndarray,
                        quats: np.ndarray) -> np.ndarray:
    """``(C,)`` the evidence each primitive gathers along a given base pose path ``(T, 3)``, ``(T, 4)``: what a
    track that believed only that primitive (``Recognizer.restrict``, as the engine's tracks per primitive do)
    and followed exactly this path would have at the end, comparable with a track's ``log_evidence``."""
    recs = [Recognizer(scorer.model.db, belief.start_spread, belief.prune).restrict([c])
            for c in range(scorer.model.n_classes)]
    return sum(gained for _, gained in _along_path(scorer, obs, positions, quats, recs))
