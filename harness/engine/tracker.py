"""The concurrent loop: particle filter, recognition and recovery, each feeding the others, frame by frame.

Per frame ``t`` (with flows ``y_t``):
1. predict: the recognition belief of ``t-1`` gives the expected base velocity (base frame); the particle
   filter moves its poses by it; the forward recursion moves its belief through the transitions;
2. weight: every particle is scored by the flows under the belief's moment-matched point distributions;
3. recognise: every active HMM state is scored at the filter's pose estimate; the forward recursion folds
   the scores in and gives the class posterior;
4. recover: angles from the recognised primitive's state belief, refined to the flows (Gauss-Newton) together
   with the base pose; the refined pose is injected back into the particle cloud (the extended proposal),
   which sharpens the next frame's weighting and recognition.

The engine reads only the observation (flows and intrinsics), the body model, and the database.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from harness import geometry
from harness.body.kinematics import geom_z_range
from harness.body.model import BodyModel
from harness.body.surface import sample_surface
from harness.engine.database import MotionDatabase
from harness.engine.features import ANGLE_RATES, ANGLES
from harness.engine.likelihood import flow_log_likelihoods, responsibilities, tempered
from harness.engine.particle_filter import ParticleFilter
from harness.engine.recognition import Recognizer
from harness.engine.recovery import refine_pose
from harness.engine.transform import database_point_distributions, patch_std, state_point_distributions, to_image
from harness.errors import EngineError
from harness.observation import Observation
from harness.pinhole import Intrinsics


@dataclass(frozen=True)
class TrackerConfig:
    """Engine settings. Distances in metres, angles in degrees, noise in pixels."""

    particles: int = 200
    model_points: int = 150
    model_seed: int = 7                      # the engine's own surface sample; independent of the markers
    init_distance: tuple[float, float] = (2.0, 8.0)
    init_elevation: tuple[float, float] = (-10.0, 40.0)
    init_factor: int = 8                     # the first frame weighs this many times more particles
    noise_px: float = 1.0                    # assumed pixel noise of flow positions
    outlier_prob: float = 0.05
    weight_iterations: int = 2               # EM steps on the model points' mixture weights per hypothesis
    weight_smoothing: float = 10.0           # pseudo-flows holding the weights towards uniform
    n_eff_filter: float = 4.0                # tempering: a frame counts as at most this many flows
    n_eff_recognition: float = 3.0
    start_spread: float = 0.05
    prune: float = 1e-4
    ess_fraction: float = 0.5
    position_noise: float = 0.15             # m / sqrt(s)
    rotation_noise: float = 0.3              # rad / sqrt(s)
    refine_iterations: int = 2              # Gauss-Newton steps per M-step
    refine_position_std: float = 0.25        # m: least pose freedom recovery has around the filter's estimate
    em_iterations: int = 3                  # re-assignments of flows to model points during recovery
    inject_fraction: float = 0.1
    jump_fraction: float = 0.06              # particles re-seeded each frame at mirrored headings

    def __post_init__(self):
        positive = {"particles": self.particles, "model_points": self.model_points,
                    "n_eff_filter": self.n_eff_filter, "n_eff_recognition": self.n_eff_recognition}
        for name, value in positive.items():
            if not value > 0:
                raise EngineError(f"engine setting {name} must be positive, got {value}")
        if self.noise_px <= 0:
            raise EngineError(f"engine setting noise_px must be positive, got {self.noise_px}")
        if not 0 < self.outlier_prob < 1:
            raise EngineError(f"engine setting outlier_prob must be in (0, 1), got {self.outlier_prob}")
        near, far = self.init_distance
        if not 0 < near < far:
            raise EngineError(f"engine setting init_distance must be [near, far] with 0 < near < far, "
                              f"got {list(self.init_distance)}")


@dataclass
class Estimate:
    """What the engine recovers. qpos ``(T, 57)``: base pose in the camera frame (OpenCV axes) and the 50
    angles; class_posterior ``(T, C)`` over ``classes``; filter_pos/filter_quat: the particle filter's
    estimate before refinement; ms_per_frame ``(T,)``; frames before the first flows are filled with the
    first estimate."""

    classes: np.ndarray
    qpos: np.ndarray
    class_posterior: np.ndarray
    filter_pos: np.ndarray
    filter_quat: np.ndarray
    ms_per_frame: np.ndarray
    timing: dict = field(default_factory=dict)

    @property
    def predicted(self) -> str:
        return str(self.classes[int(np.argmax(self.class_posterior[-1]))])


class Tracker:
    """Runs the engine on an observation sequence; ``step`` also serves live use."""

    def __init__(self, db: MotionDatabase, body: BodyModel, config: TrackerConfig = TrackerConfig(),
                 rng: np.random.Generator | None = None):
        self.db = db.validate()
        self.body = body
        self.config = config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.points = sample_surface(body, config.model_points, np.random.default_rng(config.model_seed))
        self.spread = patch_std(body, config.model_points)
        self.dists = database_point_distributions(db, body, self.points, self.spread)
        C, K, _ = db.means_.shape
        self._state_angles = db.means_[:, :, ANGLES].reshape(C * K, -1)
        self._state_angle_var = db.covars_[:, :, ANGLES].reshape(C * K, -1)
        z = geom_z_range(body, body.zero_qpos())
        self.body_height = float(z[:, 1].max() - z[:, 0].min())   # for the initial depth guess only

    # --- one sequence ---------------------------------------------------------------------------

    def run(self, obs: Observation, progress=None, base_pose: tuple[np.ndarray, np.ndarray] | None = None
            ) -> Estimate:
        """Track a whole sequence. ``base_pose`` ``((T, 3), (T, 4))`` replaces the particle filter by a
        given baselink pose in the camera frame (the ground-truth-pose baseline)."""
        obs.validate()
        if base_pose is not None and (len(base_pose[0]) != len(obs) or len(base_pose[1]) != len(obs)):
            raise EngineError(f"base_pose must have one pose per frame ({len(obs)})")
        self.reset(obs.intrinsics, obs.fps)
        for t, flows in enumerate(obs.flows):
            cam = None if obs.camera_motion is None else obs.camera_motion[t]
            self.step(flows, cam, None if base_pose is None else (base_pose[0][t], base_pose[1][t]))
            if progress is not None:
                progress(t)
        return self.result()

    def reset(self, intr: Intrinsics, fps: float) -> None:
        if not fps > 0:
            raise EngineError(f"fps must be positive, got {fps}")
        self.intr, self.fps = intr, float(fps)
        self.filter = ParticleFilter(self.config.particles, self.rng, self.config.ess_fraction,
                                     self.config.position_noise, self.config.rotation_noise)
        self.recognizer = Recognizer(self.db, self.config.start_spread, self.config.prune)
        self._started = False
        self._rows: list[tuple] = []
        self._pending: list = []      # given poses (or None) of frames before the first flows
        self._timing = {"filter": 0.0, "recognition": 0.0, "recovery": 0.0}

    def step(self, flows: np.ndarray, camera_motion: np.ndarray | None = None,
             pose: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        cfg = self.config
        flows = np.asarray(flows, dtype=float).reshape(-1, 4)
        t0 = time.perf_counter()
        if not self._started:
            if len(flows) == 0:
                self._pending.append(pose)
                return
            # A cloud init_factor times wider than the working size, narrowed by the first frame's flows.
            n = self.filter.n
            self.filter.n = n * cfg.init_factor
            self.filter.initialise(self.intr, flows, cfg.init_distance, tuple(np.deg2rad(cfg.init_elevation)),
                                   self.body_height)
            if pose is None:
                prior = self.recognizer.posterior.ravel()
                img = to_image(self.intr, geometry.to_matrix(self.filter.quats), self.filter.positions,
                               self.dists.mixture(prior), camera_motion)
                ll = flow_log_likelihoods(flows, img, cfg.noise_px, self.fps, self.intr.width, self.intr.height,
                                          cfg.outlier_prob,
                                          weight_iterations=cfg.weight_iterations, smoothing=cfg.weight_smoothing)
                self.filter.select(tempered(ll, cfg.n_eff_filter), n)
            else:
                self.filter.select(np.zeros(self.filter.n), n)
            self._started = True
        else:
            post = self.recognizer.posterior.ravel()
            self.filter.predict(post @ self.dists.base_linear, post @ self.dists.base_angular, 1.0 / self.fps,
                                camera_motion)
            self.recognizer.predict()
        W, H = self.intr.width, self.intr.height
        active = np.flatnonzero(self.recognizer.active().ravel())
        prior = self.recognizer.posterior.ravel()[active]
        states = self.dists.take(active)

        # Weight the particles under the belief's mixture.
        t1 = time.perf_counter()
        if len(flows) and pose is None:
            mix = states.mixture(prior)
            img = to_image(self.intr, geometry.to_matrix(self.filter.quats), self.filter.positions, mix,
                           camera_motion)
            ll = flow_log_likelihoods(flows, img, cfg.noise_px, self.fps, W, H, cfg.outlier_prob,
                                          weight_iterations=cfg.weight_iterations, smoothing=cfg.weight_smoothing)
            self.filter.update(tempered(ll, cfg.n_eff_filter))
        pos, quat = self.filter.estimate() if pose is None else (np.asarray(pose[0]), np.asarray(pose[1]))
        rot = geometry.to_matrix(quat)

        # Recognise at the filter's estimate.
        t2 = time.perf_counter()
        log_b = np.zeros(self.dists.pos.shape[0])
        if len(flows):
            img = to_image(self.intr, rot[None], pos[None], states, camera_motion)
            log_b[active] = tempered(flow_log_likelihoods(flows, img, cfg.noise_px, self.fps, W, H,
                                                          cfg.outlier_prob,
                                          weight_iterations=cfg.weight_iterations, smoothing=cfg.weight_smoothing), cfg.n_eff_recognition)
        self.recognizer.update(log_b.reshape(self.recognizer.log_alpha.shape))

        # Recover the angles of the recognised primitive, refine them with the pose, feed the pose back.
        t3 = time.perf_counter()
        cls_post = self.recognizer.class_posterior
        K = self.db.means_.shape[1]
        best = int(np.argmax(cls_post))
        gamma = self.recognizer.state_posterior[best]
        idx = best * K + np.arange(K)
        theta0 = gamma @ self._state_angles[idx]
        mix_rates = gamma @ self.db.means_[best][:, ANGLE_RATES]
        mix_rate_var = gamma @ (self.db.covars_[best][:, ANGLE_RATES]
                                + (self.db.means_[best][:, ANGLE_RATES] - mix_rates) ** 2)
        var = gamma @ (self._state_angle_var[idx] + (self._state_angles[idx] - theta0) ** 2)
        angles, pos_r, rot_r = theta0, pos, rot
        if len(flows):
            f = self.filter
            spread = np.sqrt(np.average((f.positions - pos) ** 2, axis=0, weights=f.weights))
            spread = np.maximum(spread, cfg.refine_position_std)
            mix = self.dists.take(idx).mixture(gamma)
            pos_r, rot_r = pos, rot
            for it in range(cfg.em_iterations):
                # E-step: soft assignment of flows to model points, first under the state belief, then at
                # the current estimate (whose points only spread over their surface patch).
                if it:
                    mix = state_point_distributions(
                        self.body, angles, np.zeros(50), mix_rates, mix_rate_var, mix.base_linear[0],
                        np.zeros(3), mix.base_angular[0], np.zeros(3), self.points, self.spread)
                img = to_image(self.intr, rot_r[None], pos_r[None], mix, camera_motion)
                resp = responsibilities(flows, img, cfg.noise_px, self.fps, W, H, cfg.outlier_prob,
                                        weight_iterations=cfg.weight_iterations, smoothing=cfg.weight_smoothing)
                # M-step: Gauss-Newton on angles and pose under the HMM prior and the filter's spread.
                angles, pos_r, rot_r = refine_pose(self.body, self.points, self.intr, flows, resp, theta0,
                                                   np.sqrt(var), pos, rot, spread, 0.3, cfg.noise_px,
                                                   self.spread, cfg.refine_iterations, start=(angles, pos_r, rot_r),
                                                   fix_pose=pose is not None)
            if pose is None:
                self.filter.inject(pos_r, geometry.from_matrix(rot_r), cfg.inject_fraction, 0.5 * spread, 0.05)
                self.filter.inject_jumps(cfg.jump_fraction)
        t4 = time.perf_counter()
        self._timing["filter"] += t2 - t1
        self._timing["recognition"] += t3 - t2
        self._timing["recovery"] += t4 - t3
        row = (np.concatenate([pos_r, geometry.from_matrix(rot_r), angles]), cls_post, pos, quat,
               1e3 * (t4 - t0))
        for given in self._pending:   # frames before the first flows take the first estimate (or their pose)
            first = row[0] if given is None else np.concatenate([given[0], given[1], row[0][7:]])
            self._rows.append((first,) + row[1:4] + (0.0,))
        self._pending = []
        self._rows.append(row)

    def result(self) -> Estimate:
        if not self._rows:
            raise EngineError("no frame had any flow: nothing to estimate")
        for _ in self._pending:
            self._rows.append(self._rows[-1][:4] + (0.0,))
        self._pending = []
        qpos, post, fpos, fquat, ms = (np.array(x) for x in zip(*self._rows))
        n = max(len(self._rows), 1)
        return Estimate(self.db.classes_.copy(), qpos, post, fpos, fquat, ms,
                        {k: 1e3 * v / n for k, v in self._timing.items()})
