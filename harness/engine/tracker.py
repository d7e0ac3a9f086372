"""The concurrent loop: pose tracks, recognition and recovery, each feeding the others, frame by frame.

Per frame (a ``Frame``: the flows and everything else the camera gave), in named stages:
1. ``propose``: every track's belief moves through the HMM transitions, and the pose source moves the tracks'
   pose hypotheses (particle tracks: by the base velocity each belief predicts, through the mixture proposal
   around the pose recovery found in the previous frame, importance-weighted);
2. ``weigh``: the pose source weighs them by the flows under each track's belief (all tracks' particles in one
   kernel call) and sets each track's pose estimate;
3. ``recognise``: each track scores its active HMM states at its pose estimate (all tracks in one kernel
   call); the forward recursion folds them in, and its normaliser is added to the track's evidence;
4. ``recover``: each track's angles from its recognised primitive's state belief, refined with its pose
   (EM and Gauss-Newton) for the tracks with the most evidence; a refined pose guides the next proposal;
5. ``reinject``: every few frames the pose source scores alternatives of the leading primitives' recent paths
   (turns, the twin, depth scales; particle tracks only) and adds one as a new track where its replayed
   evidence beats its parent's;
6. ``manage``: the pose source keeps the tracks worth keeping (particle tracks: drops those far behind the best
   in evidence, merges those that met);
7. the frame is recorded (``records``): the estimate is built from the records at the end.

Each stage receives its own settings section (``config``); the tracker holds them all.

The first frame with flows starts the tracks. The pose source is the engine's particle tracks, or a given pose
(the ground-truth-pose baseline; ``pose_source``). The engine reads only the observation (flows and
intrinsics, the optional camera motion and prior), the body model and the database.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import replace

import numpy as np

from harness import geometry
from harness.body.model import BodyModel
from harness.engine import bottom_up
from harness.engine.backward import SettledStarts, both_passes, in_forward_time, settled_starts
from harness.engine.config import TrackerConfig
from harness.engine.database import MotionDatabase
from harness.engine.estimate import Estimate
from harness.engine.frame import Frame, Frames
from harness.engine.model import EngineModel
from harness.engine.pose_source import GivenPose, ParticleTracks, PoseSource
from harness.engine.records import FrameRecord, causal_estimate, offline_estimate
from harness.engine.recovery import Recovery, mean_angles, recover
from harness.engine.reverse import reversed_flows, reversed_model
from harness.engine.scoring import Scorer
from harness.engine.track import Track
from harness.errors import EngineError
from harness.observation import Observation
from harness.pinhole import Intrinsics

STAGES = ("propose", "weigh", "recognise", "recover", "reinject", "manage")


class _Clock:
    """Wall time per stage, added to ``totals`` (seconds) as each stage ends."""

    def __init__(self, totals: dict):
        self.totals = totals
        self.start = self.last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.totals[stage] += now - self.last
        self.last = now

    def elapsed_ms(self) -> float:
        return 1e3 * (time.perf_counter() - self.start)


class Tracker:
    """Runs the engine on an observation sequence; ``reset`` + ``step`` + ``result`` serve live use.

    The tracker holds only what does not change between sequences (the model and the settings); every
    sequence's state is created by ``reset``, with the generator it is given.
    """

    def __init__(self, db: MotionDatabase, body: BodyModel, config: TrackerConfig = TrackerConfig(),
                 rng: np.random.Generator | None = None, model: EngineModel | None = None):
        self.config = config
        self.model = model if model is not None else EngineModel.build(db, body, config.model.points,
                                                                       config.model.seed)
        self.scorer = Scorer(self.model, config.likelihood)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.bottom_up = bottom_up.load_model() if config.bottomup.enabled else None

    # --- one sequence ---------------------------------------------------------------------------

    def run(self, obs: Observation, progress=None, base_pose: tuple[np.ndarray, np.ndarray] | None = None,
            rng: np.random.Generator | None = None) -> Estimate:
        """Track a whole sequence. ``base_pose`` ``((T, 3), (T, 4))`` replaces the tracks by a given baselink
        pose in the camera frame (the ground-truth-pose baseline). ``rng``: this sequence's generator (default:
        the tracker's)."""
        obs.validate()
        if base_pose is not None and (len(base_pose[0]) != len(obs) or len(base_pose[1]) != len(obs)):
            raise EngineError(f"base_pose must have one pose per frame ({len(obs)})")
        source = None if base_pose is None else GivenPose(self.scorer, self.config.belief, *base_pose)
        self.reset(obs.intrinsics, obs.fps, rng, camera_moves=obs.camera_motion is not None, source=source)
        for t, flows in enumerate(obs.flows):
            self.step(flows, None if obs.camera_motion is None else obs.camera_motion[t],
                      None if obs.gravity is None else obs.gravity[t],
                      None if obs.camera_height is None else obs.camera_height[t])
            if progress is not None:
                progress(t)
        return self.result()

    def reset(self, intr: Intrinsics, fps: float, rng: np.random.Generator | None = None,
              camera_moves: bool = False, source: PoseSource | None = None) -> None:
        """Start a sequence seen through ``intr`` at ``fps``; ``camera_moves``: the camera is not static (its
        image remembers no region of past flows); ``source``: where the base poses come from (default: the
        engine's particle tracks, with ``rng``, default the tracker's generator)."""
        self._frames = Frames(intr, fps, self.config.likelihood, camera_moves)
        self.source = source if source is not None else self.particle_tracks(rng if rng is not None else self.rng)
        self.tracks: list[Track] = []
        self.records: list[FrameRecord] = []
        self._timing = dict.fromkeys(STAGES, 0.0)
        self._inputs: list[tuple] = []           # every frame's input, for the offline backward pass
        self._sequence = (intr, fps, camera_moves)
        self._window: deque = deque(maxlen=bottom_up.WINDOW)      # the bottom-up estimate's window of flows

    def particle_tracks(self, rng: np.random.Generator, kind: type = ParticleTracks, **kw) -> ParticleTracks:
        """The engine's pose source (``kind``: ``ParticleTracks`` or a subclass, with its own ``kw``), handed the
        sections of its stages."""
        cfg = self.config
        return kind(self.scorer, rng, spawn=cfg.spawn, tracks=cfg.tracks, motion=cfg.motion,
                    reinjection=cfg.reinjection, belief=cfg.belief, min_position_std=cfg.recovery.position_std,
                    bottomup=cfg.bottomup, **kw)

    def step(self, flows: np.ndarray, camera_motion: np.ndarray | None = None, gravity: np.ndarray | None = None,
             camera_height: float | None = None) -> None:
        """One frame: flows ``(M, 4)``; the camera's own velocity ``(6,)``; the camera prior: gravity ``(3,)``
        (unit, camera frame) and the camera's height above the floor (m)."""
        frame = self._frames.next(flows, camera_motion, gravity, camera_height)
        if self.bottom_up is not None:
            self._window.append(frame.flows)
            frame = replace(frame, posture=self.bottom_up.estimate(list(self._window), frame.intr, frame.fps))
        self._inputs.append((frame.flows, frame.camera_motion, frame.gravity, frame.camera_height))
        clock = _Clock(self._timing)
        if not self.tracks and not frame.has_flows:     # nothing to start from yet: the first estimate's frame
            self.records.append(FrameRecord(frame.index, (), self.source.known_pose(frame), 0.0))
            return
        self._propose(frame)
        clock.lap("propose")
        self.source.weigh(frame, self.tracks)
        clock.lap("weigh")
        self._recognise(frame)
        clock.lap("recognise")
        self._recover(frame)
        clock.lap("recover")
        self.tracks = self.source.reinject(frame, self.tracks)
        clock.lap("reinject")
        self.tracks = self.source.manage(self.tracks)
        clock.lap("manage")
        self.records.append(FrameRecord(frame.index, tuple(t.record() for t in self.tracks),
                                        self.source.known_pose(frame), clock.elapsed_ms()))

    def _propose(self, frame: Frame) -> None:
        """The first frame with flows starts the tracks; later frames move their beliefs and poses."""
        if not self.tracks:
            self.tracks = self.source.start(frame)
            return
        for track in self.tracks:
            track.predict_belief()
        self.source.predict(frame, self.tracks)

    def _recognise(self, frame: Frame) -> None:
        """Fold the frame into every track's belief at the track's pose (all tracks in one kernel call); each
        recursion's normaliser is new evidence for its track."""
        poses = [t.pose for t in self.tracks]
        evidence = self.scorer.recognise(frame, [t.recognizer for t in self.tracks],
                                         np.array([p for p, _ in poses]), np.array([q for _, q in poses]),
                                         pose_given=self.source.fixed)
        for track, gained, pose in zip(self.tracks, evidence, poses):
            track.log_evidence += gained
            track.remember(frame.index, pose)

    def _recover(self, frame: Frame) -> None:
        """Recovery for the ``recovery.tracks`` tracks with the most evidence; the others keep their belief's
        mean angles at their filter estimate this frame (and propose without a guide next frame)."""
        settings = self.config.recovery
        ranked = sorted(self.tracks, key=lambda t: -t.log_evidence)
        refined, rest = ranked[:settings.tracks], ranked[settings.tracks:]
        weight = self.config.bottomup.recovery_weight
        for track in refined:
            pos, quat = track.pose
            rot = geometry.to_matrix(quat)
            posture = frame.posture.posture_near(rot) if frame.posture is not None and weight > 0 else None
            track.recovered(recover(self.scorer, frame, track.best_state_belief(), pos, rot,
                                    np.maximum(track.pose_std, 1e-6), settings=settings, fix_pose=self.source.fixed,
                                    posture=posture, posture_weight=weight))
        if rest:
            # The others' mean angles in one product: with dozens of tracks early on, a call each cost more.
            best, states = zip(*(t.best_states() for t in rest))
            angles = mean_angles(self.model, np.array(best), np.array(states))
            rotations = geometry.to_matrix(np.array([t.pose[1] for t in rest]))
            for track, theta, rot in zip(rest, angles, rotations):
                track.recovered(Recovery(theta, track.pose[0], rot, refined=False))

    def result(self) -> Estimate:
        """The sequence's causal estimate, with its offline (hindsight) estimate as ``offline``."""
        n, belief, settings = len(self.records), self.config.belief, self.config.offline
        causal = causal_estimate(self.records, self.model.db.classes_.copy(),
                                 {k: 1e3 * v / max(n, 1) for k, v in self._timing.items()},
                                 temperature=belief.posterior_temperature, floor=belief.posterior_floor,
                                 unknown_bias=belief.unknown_bias)
        stream = belief.primitive_switch > 0
        if settings.backward_pass and not stream and not self._sequence[2] and not self.source.fixed:
            offline = self._backward_pass()
        else:
            offline = offline_estimate(self.records, causal, settings.smoothing_frames, stream=stream)
        return replace(causal, offline=offline)

    def _backward_pass(self) -> Estimate:
        """The offline estimate of the backward pass (``backward``): the clip tracked again in reversed time
        from the poses this pass ended with, in forward time."""
        intr, fps, _ = self._sequence
        model = reversed_model(self.model)
        settings = self.config.offline
        # The bottom-up estimator learned forward time: the backward pass runs without it.
        back = Tracker(model.db, model.body, replace(self.config, offline=replace(settings, backward_pass=False),
                                                     bottomup=replace(self.config.bottomup, enabled=False)),
                       model=model)
        source = back.particle_tracks(self.source.rng, SettledStarts,
                                      starts=settled_starts(self.tracks, model.n_classes, settings.backward_live_only))
        back.reset(intr, fps, source=source)
        flows = reversed_flows([f for f, _, _, _ in self._inputs])
        for s, f in enumerate(flows):
            _, _, gravity, height = self._inputs[len(flows) - 1 - s]
            back.step(f, None, gravity, height)
        offline = in_forward_time(back.result().offline)
        if not settings.both_passes:
            return offline
        return both_passes(offline, self.records[-1], back.records[-1], self.config.belief)
