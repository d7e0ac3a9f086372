"""The concurrent loop: pose tracks, recognition and recovery, each feeding the others, frame by frame.

Per frame ``t`` (with flows ``y_t``), in named stages:
1. ``_propose``: every track moves its particles by the base velocity its belief predicts, through the mixture
   proposal around the pose recovery found in the previous frame (importance-weighted), and moves its belief
   through the HMM transitions;
2. ``_weigh``: every particle is scored by the flows under its track's moment-matched belief (all tracks'
   particles in one kernel call);
3. ``_recognise``: each track scores its active HMM states at its pose estimate; the forward recursion folds
   them in, and its normaliser is added to the track's evidence;
4. ``_recover``: each track's angles from its recognised primitive's state belief, refined with its pose
   (EM and Gauss-Newton); the refined pose guides the track's next proposal;
5. ``_manage``: tracks far behind the best in evidence are dropped, tracks that met are merged;
6. ``_record``: the class posterior is the evidence-weighted mixture of the tracks' posteriors; the pose comes
   from the track with the most evidence.

The first frame with flows spawns the tracks (``_start``). The engine reads only the observation (flows and
intrinsics), the body model and the database.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.special import softmax

from harness import geometry
from harness.body.model import BodyModel
from harness.engine.config import TrackerConfig
from harness.engine.database import MotionDatabase
from harness.engine.likelihood import flow_log_likelihoods, tempered
from harness.engine.logsum import logsumexp
from harness.engine.model import EngineModel
from harness.engine.open_region import OpenRegion
from harness.engine.particle_filter import (ParticleCloud, ProcessNoise, camera_pitch, effective_sample_size,
                                            initial_cloud, level_world, motion_mean, propose, systematic_resample)
from harness.engine.recognition import Recognizer
from harness.engine.recovery import recover
from harness.engine.switching import SwitchingRecognizer
from harness.engine.track import Recovered, Track, turned, twin
from harness.engine.transform import PointDistributions, to_image
from harness.errors import EngineError
from harness.observation import Observation
from harness.pinhole import Intrinsics

STAGES = ("propose", "weigh", "recognise", "recover", "manage")


@dataclass
class Estimate:
    """What the engine recovers. qpos ``(T, 57)``: base pose in the camera frame (OpenCV axes) and the 50
    angles, from the track with the most evidence at each frame; class_posterior ``(T, C)`` over ``classes``,
    the evidence-weighted mixture of the tracks' posteriors; joint_posterior ``(T, C, K)``: the same mixture of
    the tracks' posteriors over (primitive, state); filter_pos/filter_quat: that track's filter estimate before
    refinement; n_tracks ``(T,)``; leader ``(T,)``: the origin of the leading track;
    ms_per_frame ``(T,)``; timing: mean ms per frame of each stage. Frames before the first flows take the
    first estimate. smoothed_qpos, smoothed_class_posterior: the offline (hindsight) estimate, for evaluation
    only: the final winner's whole track smoothed, and the final class posterior at every frame."""

    classes: np.ndarray
    qpos: np.ndarray
    class_posterior: np.ndarray
    joint_posterior: np.ndarray
    filter_pos: np.ndarray
    filter_quat: np.ndarray
    n_tracks: np.ndarray
    leader: np.ndarray
    ms_per_frame: np.ndarray
    timing: dict = field(default_factory=dict)
    smoothed_qpos: np.ndarray | None = None
    smoothed_class_posterior: np.ndarray | None = None

    @property
    def predicted(self) -> str:
        return str(self.classes[int(np.argmax(self.class_posterior[-1]))])


def smooth_trajectory(qpos: np.ndarray, sigma_frames: float) -> np.ndarray:
    """Configurations ``(T, 57)`` smoothed by a Gaussian of ``sigma_frames`` frames: positions and angles
    component-wise, orientations as sign-aligned quaternions renormalised (a fixed-interval smoother)."""
    qpos = np.array(qpos, dtype=float)
    if sigma_frames <= 0 or len(qpos) < 2:
        return qpos
    quat = qpos[:, 3:7].copy()
    flip = np.cumprod(np.where(np.sum(quat[1:] * quat[:-1], axis=1) < 0, -1.0, 1.0))
    quat[1:] *= flip[:, None]
    out = gaussian_filter1d(qpos, sigma_frames, axis=0, mode="nearest")
    out[:, 3:7] = geometry.normalize(gaussian_filter1d(quat, sigma_frames, axis=0, mode="nearest"))
    return out


def floor_log_prior(points: np.ndarray, quats: np.ndarray, positions: np.ndarray, up: np.ndarray,
                    camera_height: float, config: TrackerConfig) -> np.ndarray:
    """``(N,)`` log prior of base poses from a known floor: the body's lowest point (of its model points'
    means ``points`` ``(N, P, 3)``, base frame) is on the floor, or in flight above it.

    With ``h`` the lowest point's height above the floor (camera height plus the point's camera-frame
    coordinate along ``up``): ``p(h) = (1 - f) N(h; 0, s^2) + f U(h; 0, H)`` for ``h >= 0``, the Gaussian tail
    below, with ``f = floor_flight``, ``s = floor_std``, ``H = floor_flight_height``.
    """
    rot = geometry.to_matrix(quats)
    heights = camera_height + np.einsum("i,nij,npj->np", up, rot, points) + (positions @ up)[:, None]
    h = heights.min(axis=1)
    cfg = config
    log_ground = np.log1p(-cfg.floor_flight) - 0.5 * (h / cfg.floor_std) ** 2 - np.log(np.sqrt(2 * np.pi) * cfg.floor_std)
    log_flight = np.where((h >= 0) & (h <= cfg.floor_flight_height), np.log(cfg.floor_flight / cfg.floor_flight_height),
                          -np.inf)
    return np.logaddexp(log_ground, log_flight)


def flow_log_likelihood_matrix(model_config: TrackerConfig, flows: np.ndarray, img, fps: float,
                                intr: Intrinsics, open_region: OpenRegion | None = None) -> np.ndarray:
    """``(H, M)`` per-flow log-likelihoods under projected distributions, with the engine's settings; points
    in ``open_region`` keep their prior weights (negative evidence)."""
    cfg = model_config
    held = None if open_region is None else open_region.held(img.pix)
    return flow_log_likelihoods(flows, img, cfg.noise_px, fps, intr.width, intr.height, cfg.outlier_prob,
                                weight_iterations=cfg.weight_iterations, smoothing=cfg.weight_smoothing, held=held)


def occlusion(model: EngineModel, config: TrackerConfig) -> tuple[float, float] | None:
    """``to_image``'s self-occlusion parameters (footprint radius, depth gap; metres), or None."""
    if not config.self_occlusion:
        return None
    return 2.0 * model.spread * config.occlusion_radius, config.occlusion_depth


def recognise_at(model: EngineModel, config: TrackerConfig, recognizer: Recognizer, flows: np.ndarray,
                 intr: Intrinsics, fps: float, position: np.ndarray, quat: np.ndarray,
                 camera_motion: np.ndarray | None = None, open_region: OpenRegion | None = None) -> float:
    """One recognition step at a base pose (camera frame): every active state's tempered emission, folded
    into ``recognizer``. Returns the recursion's normaliser (0 for a frame without flows)."""
    if len(flows) == 0:
        return recognizer.update(None)
    active = np.flatnonzero(recognizer.active().ravel())
    img = to_image(intr, geometry.to_matrix(quat)[None], np.asarray(position)[None], model.dists.take(active),
                   camera_motion, occlusion=occlusion(model, config))
    log_b = np.zeros(recognizer.log_alpha.size)
    log_b[active] = tempered(flow_log_likelihood_matrix(config, flows, img, fps, intr, open_region),
                             config.n_eff_recognition)
    return recognizer.update(log_b.reshape(recognizer.log_alpha.shape))


def path_evidence(model: EngineModel, config: TrackerConfig, obs: Observation, positions: np.ndarray,
                  quats: np.ndarray) -> np.ndarray:
    """``(T,)`` per-frame evidence ``log p(y_t | y_<t, path)`` of a given base pose path ``(T, 3)``, ``(T, 4)``
    (camera frame): what a track that followed exactly this path would accumulate."""
    rec = Recognizer(model.db, config.start_spread, config.prune)
    region = open_region(config, obs.intrinsics, obs.fps, obs.camera_motion is not None)
    out = np.zeros(len(obs))
    started = False
    for t, flows in enumerate(obs.flows):
        if region is not None:
            region.update(flows)
        if not started and len(flows) == 0:
            continue
        if started:
            rec.predict()
        started = True
        cam = None if obs.camera_motion is None else obs.camera_motion[t]
        out[t] = recognise_at(model, config, rec, flows, obs.intrinsics, obs.fps, positions[t], quats[t], cam, region)
    return out


def open_region(config: TrackerConfig, intr: Intrinsics, fps: float, camera_moves: bool) -> OpenRegion | None:
    """The region flows have recently shown (a moving camera remembers only the current frame), or None when
    negative evidence is off."""
    if config.open_memory_s < 0:
        return None
    memory = 0 if camera_moves else int(round(config.open_memory_s * fps))
    return OpenRegion(intr.width, intr.height, config.open_cell_px, memory)


class Tracker:
    """Runs the engine on an observation sequence; ``reset`` + ``step`` + ``result`` serve live use.

    The tracker holds only what does not change between sequences (the model and the settings); every
    sequence's state is created by ``reset``, with the generator it is given.
    """

    def __init__(self, db: MotionDatabase, body: BodyModel, config: TrackerConfig = TrackerConfig(),
                 rng: np.random.Generator | None = None, model: EngineModel | None = None):
        self.config = config
        self.model = model if model is not None else EngineModel.build(db, body, config.model_points,
                                                                       config.model_seed)
        self.rng = rng if rng is not None else np.random.default_rng(0)

    # --- one sequence ---------------------------------------------------------------------------

    def run(self, obs: Observation, progress=None, base_pose: tuple[np.ndarray, np.ndarray] | None = None,
            rng: np.random.Generator | None = None) -> Estimate:
        """Track a whole sequence. ``base_pose`` ``((T, 3), (T, 4))`` replaces the tracks by a given baselink
        pose in the camera frame (the ground-truth-pose baseline). ``rng``: this sequence's generator (default:
        the tracker's)."""
        obs.validate()
        if base_pose is not None and (len(base_pose[0]) != len(obs) or len(base_pose[1]) != len(obs)):
            raise EngineError(f"base_pose must have one pose per frame ({len(obs)})")
        self.reset(obs.intrinsics, obs.fps, rng, camera_moves=obs.camera_motion is not None)
        for t, flows in enumerate(obs.flows):
            cam = None if obs.camera_motion is None else obs.camera_motion[t]
            self.step(flows, cam, None if base_pose is None else (base_pose[0][t], base_pose[1][t]),
                      None if obs.gravity is None else obs.gravity[t],
                      None if obs.camera_height is None else float(obs.camera_height[t]))
            if progress is not None:
                progress(t)
        return self.result()

    def reset(self, intr: Intrinsics, fps: float, rng: np.random.Generator | None = None,
              camera_moves: bool = False) -> None:
        """Start a sequence seen through ``intr`` at ``fps``; ``camera_moves``: the camera is not static (its
        image remembers no region of past flows)."""
        if not fps > 0:
            raise EngineError(f"fps must be positive, got {fps}")
        self.intr, self.fps = intr, float(fps)
        self._rng = rng if rng is not None else self.rng
        self._gravity: np.ndarray | None = None
        self._height: float | None = None
        self._open = open_region(self.config, intr, self.fps, camera_moves)
        self.tracks: list[Track] = []
        self._rows: list[tuple] = []
        self._pending: list = []      # given poses (or None) of frames before the first flows
        self._timing = dict.fromkeys(STAGES, 0.0)

    def step(self, flows: np.ndarray, camera_motion: np.ndarray | None = None,
             pose: tuple[np.ndarray, np.ndarray] | None = None, gravity: np.ndarray | None = None,
             camera_height: float | None = None) -> None:
        """One frame: flows ``(M, 4)``; the camera's own velocity ``(6,)``; a given base pose (the
        ground-truth-pose baseline); the camera prior: gravity ``(3,)`` (unit, camera frame) and the camera's
        height above the floor (m)."""
        flows = np.asarray(flows, dtype=float).reshape(-1, 4)
        self._gravity = None if gravity is None else np.asarray(gravity, dtype=float)
        self._height = camera_height
        if self._open is not None:
            self._open.update(flows)
        t0 = time.perf_counter()
        clock = [t0]

        def lap(stage):
            now = time.perf_counter()
            self._timing[stage] += now - clock[0]
            clock[0] = now

        if not self.tracks:
            if len(flows) == 0:
                self._pending.append(pose)
                return
            self._start(flows, camera_motion, pose)
        else:
            self._propose(camera_motion, pose)
        lap("propose")
        if len(flows) and pose is None:
            self._weigh(flows, camera_motion)
        for track in self.tracks:
            track.estimate = (track.cloud.estimate() if pose is None
                              else (np.asarray(pose[0], float), np.asarray(pose[1], float)))
        lap("weigh")
        self._recognise(flows, camera_motion)
        lap("recognise")
        self._recover(flows, camera_motion, fixed=pose is not None)
        lap("recover")
        self._manage()
        lap("manage")
        self._record(1e3 * (time.perf_counter() - t0))

    # --- stages ---------------------------------------------------------------------------------

    def _new_recognizer(self) -> Recognizer:
        if self.config.primitive_switch > 0:
            return SwitchingRecognizer(self.model.db, self.config.primitive_switch, self.config.start_spread,
                                       self.config.prune)
        return Recognizer(self.model.db, self.config.start_spread, self.config.prune)

    def _start(self, flows: np.ndarray, camera_motion: np.ndarray | None, pose) -> None:
        """The first frame with flows: a wide cloud over the coarse prior, weighed by this frame's flows, from
        which the tracks are spawned (one track at the pose when it is given)."""
        cfg, rng = self.config, self._rng
        if pose is not None:
            pos, quat = np.asarray(pose[0], float)[None], np.asarray(pose[1], float)[None]
            self.tracks = [Track(ParticleCloud(pos, quat, np.zeros(1)), self._new_recognizer(), "given")]
            return
        n_wide = cfg.particles * cfg.init_factor
        cameras = (camera_pitch(rng.uniform(*np.deg2rad(cfg.init_elevation), n_wide)) if self._gravity is None
                   else level_world(self._gravity))
        wide = initial_cloud(self.intr, flows, n_wide, cfg.init_distance, cameras, self.model.body_height, rng)
        # Coarse to fine: every particle under the belief as one moment-matched blob, then the best
        # `init_keep` of them under a term per primitive (``_class_mixture_log_likelihood``).
        blob = to_image(self.intr, geometry.to_matrix(wide.quats), wide.positions,
                        self.model.dists.mixture(self._new_recognizer().posterior.ravel()), camera_motion,
                        occlusion=occlusion(self.model, cfg))
        coarse = tempered(self._flow_ll(flows, blob), cfg.n_eff_filter)
        wide = wide.take(np.argsort(coarse)[::-1][:int(round(cfg.init_keep * n_wide))])
        wide.reweight(self._class_mixture_log_likelihood(flows, wide, camera_motion))
        self.tracks = self._spawn(wide)

    def _spawn(self, wide: ParticleCloud) -> list[Track]:
        """The tracks of a weighted first cloud: its heaviest orientation mode (the lead), the lead's turns
        about the body's vertical, and its twin, each with an equal share of the particles."""
        cfg, rng = self.config, self._rng
        _, lead = wide.estimate()
        spawn = [("lead", lead)] + [(f"turn{a:+g}", turned(lead[None], np.deg2rad(a))[0]) for a in cfg.track_turns]
        if cfg.twin_track:
            spawn.append(("twin", twin(lead[None], self._gravity)[0]))
        n_each = cfg.particles // len(spawn)
        tracks = []
        for origin, centre in spawn:
            # The wide cloud's own particles near the track's orientation carry positions that fit it; where
            # too few are there, the lead's particles turned to it stand in.
            near = geometry.angle_between(wide.quats, centre[None]) <= np.deg2rad(45.0)
            weights = np.where(near, wide.weights, 0.0)
            if weights.sum() > 0 and effective_sample_size(weights) >= cfg.min_spawn_ess:
                cloud = wide.take(systematic_resample(weights, rng, n_each))
            else:
                lead_near = geometry.angle_between(wide.quats, lead[None]) <= np.deg2rad(45.0)
                cloud = wide.take(systematic_resample(np.where(lead_near, wide.weights, 0.0), rng, n_each))
                rel = geometry.multiply(geometry.conjugate(lead), centre)     # lead -> centre, body frame
                cloud.quats = geometry.multiply(cloud.quats, np.broadcast_to(rel, cloud.quats.shape))
            tracks.append(Track(cloud, self._new_recognizer(), origin))
        return tracks

    def _class_mixture_log_likelihood(self, flows: np.ndarray, cloud: ParticleCloud,
                                      camera_motion: np.ndarray | None) -> np.ndarray:
        """``(N,)`` tempered log-likelihood of poses under the prior over primitives, each primitive its own
        moment-matched belief: ``log sum_c p(c) p(y | x, c)``. One blob for all primitives would be so wide
        that the first frame could not tell depth; one term per state would cost ``C K`` times more."""
        C, K = self.model.n_classes, self.model.n_states
        prior = self._new_recognizer().posterior
        mixes = PointDistributions.concatenate([self.model.dists.take(np.arange(c * K, (c + 1) * K)).mixture(prior[c])
                                                for c in range(C)])
        n = len(cloud)
        index = np.repeat(np.arange(C), n)
        rot = geometry.to_matrix(cloud.quats)
        img = to_image(self.intr, np.tile(rot, (C, 1, 1)), np.tile(cloud.positions, (C, 1)), mixes, camera_motion,
                       index, occlusion(self.model, self.config))
        ll = tempered(self._flow_ll(flows, img), self.config.n_eff_filter).reshape(C, n)
        return logsumexp(ll + np.log(prior.sum(axis=1))[:, None], axis=0)

    def _propose(self, camera_motion: np.ndarray | None, pose) -> None:
        cfg, dt = self.config, 1.0 / self.fps
        n_each = cfg.particles // len(self.tracks)
        for track in self.tracks:
            # The belief moves first: a state's base velocity is over the interval ending at its own frame
            # (features.VELOCITY_SCHEME), so the states of frame t carry the base from t-1 to t.
            track.recognizer.predict()
            if pose is not None:
                track.cloud = ParticleCloud(np.asarray(pose[0], float)[None], np.asarray(pose[1], float)[None],
                                            np.zeros(1))
            else:
                v, w = track.base_velocity(self.model.dists)
                guide = guide_std = None
                rec = track.recovered
                if rec is not None and rec.refined and cfg.guide_fraction > 0:
                    g_pos, g_quat = motion_mean(rec.position[None], geometry.from_matrix(rec.rotation)[None], v, w,
                                                dt, camera_motion)
                    guide = (g_pos[0], g_quat[0])
                    guide_std = (0.5 * track.spread, cfg.guide_rotation_std)
                track.cloud = propose(track.cloud, n_each, v, w, dt, self._process_noise(), self._rng, camera_motion,
                                      guide, cfg.guide_fraction, guide_std)

    def _process_noise(self) -> ProcessNoise:
        cfg = self.config
        if self._gravity is None:
            return ProcessNoise(cfg.position_noise, cfg.rotation_noise)
        return ProcessNoise(cfg.position_noise, cfg.rotation_noise, cfg.tilt_noise, -self._gravity)

    def _flow_ll(self, flows: np.ndarray, img) -> np.ndarray:
        return flow_log_likelihood_matrix(self.config, flows, img, self.fps, self.intr, self._open)

    def _weigh(self, flows: np.ndarray, camera_motion: np.ndarray | None) -> None:
        """Every track's particles under its own belief (a mixture over its likely primitives), all tracks and
        primitives in one kernel call."""
        cfg = self.config
        mixtures = [t.class_mixtures(self.model.dists, cfg.weigh_classes, cfg.weigh_class_mass) for t in self.tracks]
        offsets = np.cumsum([0] + [len(w) for w, _ in mixtures])
        mixes = PointDistributions.concatenate([m for _, m in mixtures])
        pose_index, state_index = [], []
        start = 0
        for j, track in enumerate(self.tracks):
            n = len(track.cloud)
            for c in range(offsets[j], offsets[j + 1]):
                pose_index.append(np.arange(start, start + n))
                state_index.append(np.full(n, c))
            start += n
        pose_index, state_index = np.concatenate(pose_index), np.concatenate(state_index)
        pos = np.concatenate([t.cloud.positions for t in self.tracks])[pose_index]
        quat = np.concatenate([t.cloud.quats for t in self.tracks])[pose_index]
        img = to_image(self.intr, geometry.to_matrix(quat), pos, mixes, camera_motion, state_index,
                       occlusion(self.model, cfg))
        ll = tempered(self._flow_ll(flows, img), cfg.n_eff_filter)
        if self._height is not None:
            ll = ll + floor_log_prior(mixes.pos[state_index], quat, pos, -self._gravity, self._height, cfg)
        at = 0
        for (log_w, _), track in zip(mixtures, self.tracks):
            n, k = len(track.cloud), len(log_w)
            part = ll[at:at + n * k].reshape(k, n)
            track.cloud.reweight(logsumexp(part + log_w[:, None], axis=0))
            at += n * k

    def _recognise(self, flows: np.ndarray, camera_motion: np.ndarray | None) -> None:
        """Each track's states scored at its pose; the recursion's normaliser is the track's new evidence."""
        for track in self.tracks:
            pos, quat = track.estimate
            track.log_evidence += recognise_at(self.model, self.config, track.recognizer, flows, self.intr,
                                               self.fps, pos, quat, camera_motion, self._open)

    def _recover(self, flows: np.ndarray, camera_motion: np.ndarray | None, fixed: bool) -> None:
        """Recovery for the ``recover_tracks`` tracks with the most evidence; the others keep their belief's
        mean angles at their filter estimate this frame (and propose without a guide next frame)."""
        cfg = self.config
        ranked = sorted(self.tracks, key=lambda t: -t.log_evidence)
        for rank, track in enumerate(ranked):
            pos, quat = track.estimate
            track.spread = (np.zeros(3) if fixed
                            else np.maximum(track.cloud.spread(), cfg.refine_position_std))
            refine = rank < cfg.recover_tracks
            angles, pos_r, rot_r = recover(self.model, flows if refine else flows[:0], self.intr, self.fps,
                                           track.best_state_belief(), pos, geometry.to_matrix(quat),
                                           np.maximum(track.spread, 1e-6), cfg, camera_motion, fix_pose=fixed,
                                           occlusion=occlusion(self.model, cfg), open_region=self._open)
            track.recovered = Recovered(angles, pos_r, rot_r, refined=refine)

    def _manage(self) -> None:
        """Drop tracks trailing the best by ``track_prune_nats``; of two tracks that met (orientation within
        ``track_merge_deg`` and position within ``track_merge_m``), keep the one with more evidence."""
        cfg = self.config
        best = max(t.log_evidence for t in self.tracks)
        kept = [t for t in self.tracks if t.log_evidence >= best - cfg.track_prune_nats]
        kept.sort(key=lambda t: -t.log_evidence)
        merged: list[Track] = []
        for track in kept:
            pos, quat = track.estimate
            if not any(np.linalg.norm(pos - m.estimate[0]) < cfg.track_merge_m
                       and geometry.angle_between(quat, m.estimate[1]) < np.deg2rad(cfg.track_merge_deg)
                       for m in merged):
                merged.append(track)
        self.tracks = merged

    def _record(self, ms: float) -> None:
        evidence = np.array([t.log_evidence for t in self.tracks])
        share = softmax(evidence)
        joint = np.einsum("j,jck->ck", share, np.array([t.recognizer.posterior for t in self.tracks]))
        joint /= joint.sum()
        for track in self.tracks:
            rec = track.recovered
            track.history.append(np.concatenate([rec.position, geometry.from_matrix(rec.rotation), rec.angles]))
        lead = self.tracks[int(np.argmax(evidence))]
        row = (lead.history[-1], joint.sum(axis=1), joint, lead.estimate[0], lead.estimate[1], len(self.tracks),
               lead.origin, ms)
        for given in self._pending:   # frames before the first flows take the first estimate (or their pose)
            first = row[0] if given is None else np.concatenate([given[0], given[1], row[0][7:]])
            self._rows.append((first,) + row[1:7] + (0.0,))
        self._pending = []
        self._rows.append(row)

    def result(self) -> Estimate:
        if not self._rows:
            raise EngineError("no frame had any flow: nothing to estimate")
        for _ in self._pending:
            self._rows.append(self._rows[-1][:7] + (0.0,))
        self._pending = []
        qpos, post, joint, fpos, fquat, n_tracks, leader, ms = (np.array(x) for x in zip(*self._rows))
        n = len(self._rows)
        return Estimate(self.model.db.classes_.copy(), qpos, post, joint, fpos, fquat, n_tracks, leader, ms,
                        {k: 1e3 * v / n for k, v in self._timing.items()}, *self._hindsight(qpos, post))

    def _hindsight(self, causal_qpos: np.ndarray, causal_post: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The offline estimate: the whole trajectory of the track with the most evidence at the end, smoothed
        over ``smoothing_frames``, and every frame's class posterior the last frame's ``p(c | y_1:T)`` (one
        primitive per clip; a stream, ``primitive_switch > 0``, keeps its causal posteriors)."""
        lead = max(self.tracks, key=lambda t: t.log_evidence)
        T = len(causal_qpos)
        if lead.origin == "given" or len(lead.history) == 0:
            path = causal_qpos
        else:
            path = np.array(lead.history)
            first = T - len(path)                 # frames before the track's first: its first pose
            path = np.concatenate([np.repeat(path[:1], first, axis=0), path]) if first > 0 else path[-T:]
        post = causal_post if self.config.primitive_switch > 0 else np.repeat(causal_post[-1:], T, axis=0)
        return smooth_trajectory(path, self.config.smoothing_frames), post
