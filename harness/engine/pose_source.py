"""Where the tracks' base poses come from: the stages of the loop that are the pose source's own.

A pose source answers, each frame, for the tracks it made (``PoseSource``):

- ``start(frame)``: the tracks of the first frame with flows;
- ``predict(frame, tracks)``: move each track's pose hypotheses to this frame (its belief has moved already);
- ``weigh(frame, tracks)``: weigh them by the frame's flows and set each track's pose estimate;
- ``reinject(frame, tracks)``: after recovery, the tracks with new ones added where an alternative of a track's
  recent path (a turn, the twin, a depth scale) has more evidence than the track (particle tracks, every few
  frames; none for a given pose);
- ``manage(tracks)``: last, the tracks that go on;
- ``known_pose(frame)``: the base pose it knows without tracking (a given pose), or None;
- ``fixed``: whether recovery must keep the base pose (it is given).

Two sources: ``ParticleTracks`` (the engine: pose tracks of particle clouds, spawned at the first frame's
heaviest orientation mode, its turns and its twin) and ``GivenPose`` (the baseline handed the true pose).
"""

from __future__ import annotations

import copy
from collections import deque
from typing import Protocol

import numpy as np

from harness import geometry
from harness.body.model import mirror_angles
from harness.engine.config import (BeliefSettings, BottomUpSettings, MotionSettings, ReinjectionSettings,
                                   SpawnSettings, TracksSettings)
from harness.engine.frame import Frame
from harness.engine.logsum import logsumexp
from harness.engine.particle_filter import (ParticleCloud, ProcessNoise, camera_pitch, effective_sample_size,
                                            initial_cloud, level_world, propose_many, reweight_many, settled,
                                            systematic_resample)
from harness.engine.recognition import Recognizer
from harness.engine.recovery import Recovery
from harness.engine.scoring import Scorer
from harness.engine.track import (Alternative, Snapshot, Track, alternatives, new_recognizer, prune_and_merge, turned,
                                  twin)
from harness.errors import EngineError


class PoseSource(Protocol):
    """The pose source's part of the loop (module docstring)."""

    fixed: bool

    def start(self, frame: Frame) -> list[Track]: ...

    def predict(self, frame: Frame, tracks: list[Track]) -> None: ...

    def weigh(self, frame: Frame, tracks: list[Track]) -> None: ...

    def reinject(self, frame: Frame, tracks: list[Track]) -> list[Track]: ...

    def manage(self, tracks: list[Track]) -> list[Track]: ...

    def known_pose(self, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None: ...


class GivenPose:
    """One track at a given base pose per frame, ``positions (T, 3)`` and ``quats (T, 4)`` in the camera frame
    (the ground-truth-pose baseline): recognition and recovery without tracking."""

    fixed = True

    def __init__(self, scorer: Scorer, belief: BeliefSettings, positions: np.ndarray, quats: np.ndarray):
        if len(positions) != len(quats):
            raise EngineError(f"a given pose needs as many positions as orientations, got {len(positions)} and "
                              f"{len(quats)}")
        self.scorer, self.belief_settings = scorer, belief
        self.positions, self.quats = positions, quats

    def __len__(self) -> int:
        return len(self.positions)

    def known_pose(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        if frame.index >= len(self):
            raise EngineError(f"the given pose has {len(self)} frames; frame {frame.index} has none")
        return self.positions[frame.index], self.quats[frame.index]

    def start(self, frame: Frame) -> list[Track]:
        return [Track(0, "given", new_recognizer(self.scorer.model.db, self.belief_settings))]

    def predict(self, frame: Frame, tracks: list[Track]) -> None:
        pass

    def weigh(self, frame: Frame, tracks: list[Track]) -> None:
        for track in tracks:
            track.place(*self.known_pose(frame))

    def reinject(self, frame: Frame, tracks: list[Track]) -> list[Track]:
        return tracks

    def manage(self, tracks: list[Track]) -> list[Track]:
        return tracks


class ParticleTracks:
    """The engine's pose tracks, each a particle cloud with its own belief (``track``), sharing
    ``tracks.particles`` particles: spawned at the first frame with flows, moved by their beliefs, weighed by
    the flows under their beliefs, pruned and merged by evidence. Settings: the sections of its stages
    (``harness.engine.config``); ``min_position_std``: the least position room a track's pose gives recovery
    (``recovery.position_std``)."""

    fixed = False

    def __init__(self, scorer: Scorer, rng: np.random.Generator, *, spawn: SpawnSettings, tracks: TracksSettings,
                 motion: MotionSettings, reinjection: ReinjectionSettings, belief: BeliefSettings,
                 min_position_std: float, bottomup: BottomUpSettings = BottomUpSettings()):
        self.scorer = scorer
        self.bottomup_settings = bottomup
        self.rng = rng
        self.spawn_settings, self.track_settings, self.motion_settings = spawn, tracks, motion
        self.reinjection_settings, self.belief_settings = reinjection, belief
        self.min_position_std = min_position_std
        self._spawned = 0
        self._frames: dict[int, Frame] = {}      # the frames re-injection replays
        self._alternatives = alternatives(reinjection)
        self._screened: dict = {}                # re-injection's screened snapshots (``screen``)
        self._drawn_at: int | None = None        # the frame whose weighing ``start`` drew the tracks from
        self._belief = new_recognizer(scorer.model.db, belief)    # ``new_belief``'s original

    def new_belief(self) -> Recognizer:
        """A new track's belief (``track.new_recognizer``), copied: building one checks the whole database and
        derives its start (0.2 ms, about 70 times a clip)."""
        return copy.copy(self._belief)

    @property
    def memory(self) -> int:
        """Snapshots each track keeps: the window re-injection replays, and the one before it (none without
        re-injection)."""
        cfg = self.reinjection_settings
        return cfg.window + 1 if cfg.every else 0

    def known_pose(self, frame: Frame) -> None:
        return None

    def share(self, n_tracks: int) -> int:
        """Particles per track when ``n_tracks`` share them: an equal share of ``particles`` (at least one), at
        most ``track_particles_max``."""
        cfg = self.track_settings
        return min(max(1, cfg.particles // n_tracks), cfg.particles_max)

    # --- the first frame ------------------------------------------------------------------------

    def start(self, frame: Frame) -> list[Track]:
        """A wide cloud over the coarse prior, weighed by the first frame's flows, and the tracks spawned from it:
        with ``class_tracks``, a set per primitive from that primitive's own weighing of the cloud, each believing
        only its primitive; else one set from the cloud weighed under the mixture of primitives."""
        wide, per_class, log_prior = self.first_cloud(frame)
        if not self.class_tracks:
            wide.reweight(logsumexp(per_class + log_prior[:, None], axis=0))
            return self.spawn(wide, frame.gravity)
        # Each primitive's tracks are drawn from the frame's weighing under that primitive, the likelihood ``weigh``
        # applies to them: this frame is in them already. (A stream's tracks are drawn from the mixture's
        # weighing, which its weighing under every primitive alike does not repeat.)
        self._drawn_at = frame.index
        C = len(per_class)
        n_each = self.share(C * self.spawn_settings.n_tracks)
        owns = [ParticleCloud(wide.positions, wide.quats, wide.log_weights.copy()) for _ in range(C)]
        reweight_many(owns, per_class)
        tracks = []
        for c, own in enumerate(owns):
            tracks += self.spawn(own, frame.gravity, primitive=c, n_each=n_each)
        return tracks

    @property
    def class_tracks(self) -> bool:
        """Whether tracks hypothesise one primitive each (not in streams, where the primitive changes)."""
        return self.spawn_settings.per_class and self.belief_settings.primitive_switch == 0

    def first_cloud(self, frame: Frame) -> tuple[ParticleCloud, np.ndarray, np.ndarray]:
        """``init_factor`` times the particles from the coarse prior, weighed coarse to fine: every particle
        under the prior as one moment-matched blob, then the best ``init_keep`` of them (equally weighted) under
        each primitive (``class_log_likelihoods``). Returns that cloud, the log-likelihoods ``(C, N)`` and the
        primitives' log prior ``(C,)``."""
        cfg, model, rng = self.spawn_settings, self.scorer.model, self.rng
        n_wide = self.track_settings.particles * cfg.factor
        cameras = (camera_pitch(rng.uniform(*np.deg2rad(cfg.elevation), n_wide)) if frame.gravity is None
                   else level_world(frame.gravity))
        wide = initial_cloud(frame.intr, frame.flows, n_wide, rng, depth_range=cfg.distance,
                             world_from_camera=cameras, body_extent=model.body_extent,
                             band=cfg.depth_band)
        wide = self.with_bottom_up(wide, frame)
        prior = self._belief.posterior
        coarse = self.scorer.pose_log_likelihood(frame, wide.quats, wide.positions, model.dists.mixture(prior.ravel()),
                                                 n_eff=self.scorer.settings.n_eff_filter)
        wide = wide.take(np.argsort(coarse)[::-1][:int(round(cfg.keep * n_wide))])
        return wide, self.class_log_likelihoods(frame, wide, prior), np.log(prior.sum(axis=1))

    def with_bottom_up(self, wide: ParticleCloud, frame: Frame) -> ParticleCloud:
        """The first cloud with its last ``bottomup.spawn_share`` replaced by draws about the bottom-up estimate's
        two poses (``PostureEstimate.pose_modes``, half each): the first frame's pose prior is then the mixture
        ``(1 - a) p_coarse + a g`` of the coarse prior and the estimate's distribution ``g`` (rotation noise of
        the estimate's own std, at least ``spawn_rotation_std``; the depth's log with its std, at least
        ``spawn_depth_std``, along the ray of the estimate's base point). Particles are exact draws of that prior,
        so the weighing that follows needs no correction. Unchanged without an estimate."""
        cfg, est = self.bottomup_settings, frame.posture
        n = int(round(cfg.spawn_share * len(wide))) if est is not None else 0
        if n == 0:
            return wide
        rng = self.rng
        modes = est.pose_modes()
        which = rng.random(n) < 0.5
        rot = np.where(which[:, None, None], modes[1][0], modes[0][0])
        rot_std = max(est.rotation_std, cfg.spawn_rotation_std)
        quats = geometry.multiply(geometry.exp(rng.normal(size=(n, 3)) * rot_std), geometry.from_matrix(rot))
        depth = np.exp(rng.normal(size=n) * max(est.log_depth_std, cfg.spawn_depth_std))
        positions = est.position[None] * depth[:, None]
        keep = len(wide) - n
        return ParticleCloud(np.concatenate([wide.positions[:keep], positions]),
                             np.concatenate([wide.quats[:keep], geometry.normalize(quats)]), wide.log_weights.copy())

    def class_log_likelihoods(self, frame: Frame, cloud: ParticleCloud, prior: np.ndarray) -> np.ndarray:
        """``(C, N)`` tempered log-likelihoods ``log p(y | x, c)`` of poses under each primitive, each its own
        moment-matched belief (the prior ``(C, K)`` over its states). One blob for all primitives would be so
        wide that the first frame could not tell depth; one term per state would cost ``K`` times more."""
        model = self.scorer.model
        C, K = model.n_classes, model.n_states
        mixes = model.dists.mixtures(np.einsum("ck,cd->cdk", prior, np.eye(C)).reshape(C, C * K))
        n = len(cloud)
        return self.scorer.pose_log_likelihood(frame, np.tile(cloud.quats, (C, 1)), np.tile(cloud.positions, (C, 1)),
                                               mixes, np.repeat(np.arange(C), n),
                                               n_eff=self.scorer.settings.n_eff_filter).reshape(C, n)

    def spawn(self, wide: ParticleCloud, gravity: np.ndarray | None, *, primitive: int | None = None,
              n_each: int | None = None) -> list[Track]:
        """The tracks of a weighted first cloud: its heaviest orientation mode (the lead), the lead's turns
        about the body's vertical, and its twin, with ``n_each`` particles each (default: an equal share of all).
        A track starts from the cloud's own particles within 45 degrees of its orientation (their positions fit
        it); where they hold fewer than ``min_spawn_ess`` effective particles, from the lead's particles turned
        to it. With ``primitive``, the tracks believe only that primitive (``Recognizer.restrict``)."""
        cfg, rng = self.spawn_settings, self.rng
        _, lead = wide.estimate()
        spawn = [("lead", lead)] + [(f"turn{a:+g}", turned(lead[None], np.deg2rad(a))[0]) for a in cfg.turns]
        if cfg.twin:
            spawn.append(("twin", twin(lead[None], gravity)[0]))
        if n_each is None:
            n_each = self.share(len(spawn))
        prefix = "" if primitive is None else f"{self.scorer.model.db.classes_[primitive]}/"
        tracks = []
        for origin, centre in spawn:
            near = geometry.angle_between(wide.quats, centre[None]) <= np.deg2rad(45.0)
            weights = np.where(near, wide.weights, 0.0)
            if weights.sum() > 0 and effective_sample_size(weights) >= cfg.min_ess:
                cloud = wide.take(systematic_resample(weights, rng, n_each))
            else:
                lead_near = geometry.angle_between(wide.quats, lead[None]) <= np.deg2rad(45.0)
                cloud = wide.take(systematic_resample(np.where(lead_near, wide.weights, 0.0), rng, n_each))
                rel = geometry.multiply(geometry.conjugate(lead), centre)     # lead -> centre, body frame
                cloud.quats = geometry.multiply(cloud.quats, np.broadcast_to(rel, cloud.quats.shape))
            belief = self.new_belief()
            if primitive is not None:
                belief.restrict([primitive])
            tracks.append(Track(self._spawned, prefix + origin, belief, cloud, primitive=primitive, memory=self.memory))
            self._spawned += 1
        return tracks

    # --- every frame ----------------------------------------------------------------------------

    def process_noise(self, gravity: np.ndarray | None) -> ProcessNoise:
        cfg = self.motion_settings
        if gravity is None:
            return ProcessNoise(cfg.position_noise, cfg.rotation_noise)
        return ProcessNoise(cfg.position_noise, cfg.rotation_noise, cfg.tilt_noise, -gravity)

    def predict(self, frame: Frame, tracks: list[Track]) -> None:
        """Move every track's particles: the tracks recovery guides one by one (``Track.move``), the others in
        one bootstrap pass (``propose_many``), each at its belief's base velocity."""
        cfg = self.motion_settings
        n_each = self.share(len(tracks))
        noise = self.process_noise(frame.gravity)
        dists = self.scorer.model.dists
        guided, free = [], []
        for track in tracks:
            (guided if track.guided(cfg) else free).append(track)
        if guided:      # the recovered rotations' quaternions in one call: a call each cost 40 us of numpy
            quats = geometry.from_matrix(np.array([t.recovery.rotation for t in guided]))
            for track, quat in zip(guided, quats):
                track.move(frame, dists, n_each, noise, self.rng, cfg, recovered_quat=quat)
        if free:
            velocity = [t.base_velocity(dists) for t in free]
            clouds = propose_many([t.cloud for t in free], n_each, noise, self.rng,
                                  base_linear=np.array([v for v, _ in velocity]),
                                  base_angular=np.array([w for _, w in velocity]), dt=frame.dt,
                                  camera_motion=frame.camera_motion)
            for track, cloud in zip(free, clouds):
                track.cloud = cloud

    def log_likelihoods(self, frame: Frame, tracks: list[Track]) -> list[np.ndarray]:
        """Each track's particles' log-likelihoods ``(N_j,)`` under its own belief (``Track.pose_mixture``): all
        tracks and mixture terms in one kernel call."""
        mixtures = [t.pose_mixture(self.track_settings) for t in tracks]
        pose_index, state_index = mixture_pairs([len(t.cloud) for t in tracks], [len(w) for w, _ in mixtures])
        mixes = self.posture_distributions(frame, tracks, mixtures) if self.bottomup_settings.weigh_posture else None
        if mixes is None:
            mixes = self.scorer.model.dists.mixtures(np.concatenate([rows for _, rows in mixtures]))
        pos = np.concatenate([t.cloud.positions for t in tracks])[pose_index]
        quat = np.concatenate([t.cloud.quats for t in tracks])[pose_index]
        ll = self.scorer.pose_log_likelihood(frame, quat, pos, mixes, state_index,
                                             n_eff=self.scorer.settings.n_eff_filter)
        out, at = [], 0
        for (log_w, _), track in zip(mixtures, tracks):
            n, k = len(track.cloud), len(log_w)
            # One term (a track of one primitive, or a stream's blob): the sum over one term, without its call.
            out.append(ll[at:at + n] + log_w[0] if k == 1 else
                       logsumexp(ll[at:at + n * k].reshape(k, n) + log_w[:, None], axis=0))
            at += n * k
        return out

    def posture_distributions(self, frame: Frame, tracks: list[Track], mixtures: list):
        """Each track's belief fused with the bottom-up posture of the estimate's mode nearer the track's pose
        (``Scorer.posture_distributions``; ``PostureEstimate.posture_near``), one term per track, or None
        without an estimate or when a track's belief is a mixture of several terms (streams weighed by
        belief)."""
        est = frame.posture
        if est is None:
            return None
        if any(len(w) != 1 for w, _ in mixtures):
            return None
        quats = np.array([t.pose[1] if t.pose is not None else t.cloud.estimate()[1] for t in tracks])
        postures = [est.posture_near(r) for r in geometry.to_matrix(quats)]
        return self.scorer.posture_distributions(np.concatenate([rows for _, rows in mixtures]), postures, 1.0)

    def weigh(self, frame: Frame, tracks: list[Track]) -> None:
        if self.reinjection_settings.every:
            self._frames[frame.index] = frame
            self._frames.pop(frame.index - self.memory, None)
        # The tracks per primitive ``start`` drew from this frame's weighing hold it already: weighed again, the
        # first frame would count twice (docs/engine.md, "Pose tracks").
        if frame.has_flows and frame.index != self._drawn_at:
            reweight_many([t.cloud for t in tracks], self.log_likelihoods(frame, tracks))
        positions, quats, spreads = settled([t.cloud for t in tracks])
        for track, pos, quat, spread in zip(tracks, positions, quats, spreads):
            track.settle(pos, quat, spread, self.min_position_std)

    def reinject(self, frame: Frame, tracks: list[Track]) -> list[Track]:
        """Every ``reinject_every`` frames, alternatives to the paths of the best track of each of the
        ``reinject_classes`` primitives with the most evidence (``track.alternatives``: turns, the twin, depth
        scales) over the last ``reinject_window`` frames; a parent's best alternative becomes a new track when its
        score beats the parent's evidence by ``reinject_margin``.

        The newcomer's score is the evidence of the path it claims, its parent's path until the window and its
        own over the window, less ``log A`` for having been picked as the best of ``A`` alternatives (a
        uniform prior over them):

            L_new = L_parent(t0 - 1) + sum_{s=t0..t} log p(y_s | y_<s, alternative path) - log A

        the forward recursion continued from the parent's belief at ``t0 - 1`` (``replay``), so that it is
        comparable with every other track's evidence. Replaying every alternative would cost ``A`` recursions per
        parent; they are screened first (``screen``: each frame's flows under the parent's belief moment-matched,
        one hypothesis per alternative and frame) and only the best, if it screens above the parent's own path,
        is replayed."""
        cfg = self.reinjection_settings
        if not cfg.every or not self._alternatives or (frame.index + 1) % cfg.every:
            return tracks
        best: dict = {}
        for t in sorted(tracks, key=lambda t: -t.log_evidence):
            best.setdefault(t.primitive, t)
        parents = list(best.values())[:cfg.classes]
        own = Alternative("own")
        screened, self._screened = screen(self.scorer, self._frames, [p.history for p in parents],
                                          [own] + self._alternatives, self._screened)
        # The bottom-up estimate's poses, as each parent's turn and depth scale to them (their own screen: they
        # differ from parent to parent, so the cache of the common alternatives does not hold them).
        extras = [self.bottom_up_alternatives(p, frame) for p in parents]
        jobs = []
        for parent, s, alts in zip(parents, screened, extras):
            scored = list(zip(s[1:], self._alternatives))
            if alts:
                own_too = screen(self.scorer, self._frames, [parent.history], [own] + alts)[0][0]
                scored += list(zip(own_too[1:], alts))
            best, alt = max(scored, key=lambda c: c[0])
            if best > s[0]:
                jobs.append((parent, alt))
        replayed = replay(self.scorer, self._frames, [p.history for p, _ in jobs], [a for _, a in jobs])
        penalty = np.log(len(self._alternatives) + max((len(a) for a in extras), default=0))
        out = list(tracks)
        for (parent, alt), (score, rec, history) in zip(jobs, replayed):
            score -= penalty
            if score <= parent.log_evidence + cfg.margin:
                continue
            pos, quat = alt.apply(parent.cloud.positions, parent.cloud.quats, frame.gravity)
            cloud = ParticleCloud(pos, quat, parent.cloud.log_weights.copy())
            newcomer = Track(self._spawned, f"{parent.origin}>{alt.name}@{frame.index}", rec, cloud,
                             primitive=parent.primitive, memory=self.memory, log_evidence=score,
                             parent=parent.id)
            # Its path until the window is its parent's: a later replay of it may start there.
            newcomer.history = deque([parent.history[0], *history], maxlen=self.memory)
            newcomer.pose, newcomer.pose_std = history[-1].pose, parent.pose_std.copy()
            angles = parent.recovery.angles
            newcomer.recovered(Recovery(mirror_angles(angles) if alt.twin else angles, newcomer.pose[0],
                                        geometry.to_matrix(newcomer.pose[1]), refined=False))
            self._spawned += 1
            out.append(newcomer)
        return out

    def bottom_up_alternatives(self, parent: Track, frame: Frame) -> list[Alternative]:
        """Re-injection's alternatives towards the bottom-up estimate (``bottomup.reinject``): for each of its two
        poses, the turn about the parent's vertical that brings the parent's orientation nearest to it and the
        depth scale to its depth (within 0.5-2), applied to the parent's recent path like every alternative.
        None without an estimate."""
        est = frame.posture
        if est is None or not self.bottomup_settings.reinject or not self.reinjection_settings.every:
            return []
        rot = geometry.to_matrix(parent.pose[1])
        depth = float(np.clip(est.position[2] / parent.pose[0][2], 0.5, 2.0))
        out = []
        for k, (mode, _) in enumerate(est.pose_modes()):
            rel = rot.T @ mode
            out.append(Alternative(f"bottomup{k}", turn=float(np.arctan2(rel[1, 0], rel[0, 0])), depth=depth))
        return out

    def manage(self, tracks: list[Track]) -> list[Track]:
        cfg = self.track_settings
        return prune_and_merge(tracks, cfg.prune_nats, cfg.merge_m, cfg.merge_deg)


def screen(scorer: Scorer, frames: dict[int, Frame], histories: list, alternatives: list[Alternative],
           cache: dict | None = None) -> tuple[list, dict]:
    """For each track history: ``(A,)`` the tempered log-likelihood summed over its later frames of each
    alternative's transform of its poses, under the track's belief of that frame moment-matched over its
    primitives' active states (one hypothesis per alternative and frame, all in one kernel call per frame).

    ``cache``: the rows ``(A,)`` of snapshots already screened against the same ``alternatives`` (by
    ``id``, with the snapshot kept alive beside its row); the windows of successive calls overlap, so each
    snapshot is scored once. Returns the sums and the cache of this call's snapshots."""
    cache = cache or {}
    rows, owners, known = [], [], {}
    for h in histories:
        for snap in list(h)[1:]:
            if id(snap) in cache:
                known[id(snap)] = cache[id(snap)]
                continue
            rec = snap.recognizer
            rows.append(np.where(rec.active(), rec.posterior, 0.0).ravel())
            owners.append(snap)
    A = len(alternatives)
    scored = {id(snap): (snap, np.zeros(A)) for snap in owners}
    blobs = scorer.model.dists.mixtures(np.array(rows)) if rows else None
    by_frame: dict[int, list[int]] = {}
    for i, snap in enumerate(owners):
        by_frame.setdefault(snap.index, []).append(i)
    for index, members in by_frame.items():
        frame = frames[index]
        if not frame.has_flows:
            continue
        pos = np.array([owners[i].pose[0] for i in members])
        quat = np.array([owners[i].pose[1] for i in members])
        moved = [alt.apply(pos, quat, frame.gravity) for alt in alternatives]     # member-major below
        ll = scorer.pose_log_likelihood(
            frame,
            np.stack([q for _, q in moved], axis=1).reshape(-1, 4),
            np.stack([p for p, _ in moved], axis=1).reshape(-1, 3),
            blobs,
            np.repeat(members, A),
            n_eff=scorer.settings.n_eff_recognition,
        ).reshape(len(members), A)
        for i, row in zip(members, ll):
            scored[id(owners[i])][1][:] = row
    known |= scored
    out = [sum((known[id(snap)][1] for snap in list(h)[1:]), np.zeros(A)) for h in histories]
    return out, known


def replay(scorer: Scorer, frames: dict[int, Frame], histories: list, alternatives: list[Alternative]) -> list:
    """For each (track history, alternative): the forward recursion continued from the history's first
    snapshot's belief through its later frames, at the alternative's transform of the poses the track was
    evaluated at (all replays' frames scored in one kernel call per frame). Returns per pair ``(evidence,
    recognizer, snapshots)``: the first snapshot's evidence plus the replayed normalisers, the belief at the
    end, and the replayed snapshots (``track.Snapshot``, the alternative's poses)."""
    recs = [copy.copy(h[0].recognizer) for h in histories]
    evidence = np.array([h[0].log_evidence for h in histories])
    snaps: list[list[Snapshot]] = [[] for _ in histories]
    steps = max((len(h) for h in histories), default=1) - 1
    for i in range(1, steps + 1):
        live = [j for j, h in enumerate(histories) if i < len(h)]
        by_frame: dict[int, list[int]] = {}
        for j in live:
            by_frame.setdefault(histories[j][i].index, []).append(j)
        for index, members in by_frame.items():
            frame = frames[index]
            poses = [alternatives[j].apply(histories[j][i].pose[0][None], histories[j][i].pose[1][None],
                                           frame.gravity) for j in members]
            for j in members:
                recs[j].predict()
            gained = scorer.recognise(frame, [recs[j] for j in members], np.concatenate([p for p, _ in poses]),
                                      np.concatenate([q for _, q in poses]))
            for j, g, (p, q) in zip(members, gained, poses):
                evidence[j] += g
                snaps[j].append(Snapshot(index, (p[0], q[0]), copy.copy(recs[j]), float(evidence[j])))
    return [(float(e), r, s) for e, r, s in zip(evidence, recs, snaps)]


def mixture_pairs(particles: list[int], terms: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The (particle, mixture term) pairs of a batched weighing: track ``j`` has ``particles[j]`` particles
    and ``terms[j]`` terms; its pairs run term by term, each over all its particles. Returns the particle index
    into the tracks' concatenated particles and the term index into their concatenated terms, ``(sum_j n_j
    k_j,)`` each."""
    pose_index, state_index = [], []
    start, term = 0, 0
    for n, k in zip(particles, terms):
        for c in range(term, term + k):
            pose_index.append(np.arange(start, start + n))
            state_index.append(np.full(n, c))
        start, term = start + n, term + k
    return np.concatenate(pose_index), np.concatenate(state_index)
