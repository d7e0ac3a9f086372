"""The engine's settings: every tuned constant by name, with where its value came from."""

from __future__ import annotations

from dataclasses import dataclass

from harness.errors import EngineError


@dataclass(frozen=True)
class TrackerConfig:
    """Engine settings. Distances in metres, angles in degrees unless a name says rad, noise in pixels.
    Where a value was chosen by measurement, the comment says on what."""

    particles: int = 500                     # in total over all tracks (200 before the tracks per primitive)
    track_particles_max: int = 50            # ... and at most this many per track
                                             # (it binds once ten or fewer are left; 240 development runs, seeds
                                             # 101-103, against no cap:
                                             # `full` 0 fixed, 1 lost, heading -0.5 deg, smoothed 5 / 1 and
                                             # -6.0 deg, 36% less time; 25: 4 / 4; docs/engine.md)
    model_points: int = 120                  # the engine's own surface sample, spread evenly
                                             # (150 drawn at random until 2026-12-06; docs/engine.md, "Speed")
    model_seed: int = 7                      # ... seeded independently of the markers
    init_distance: tuple[float, float] = (2.0, 8.0)    # prior range of the subject's distance
    init_elevation: tuple[float, float] = (-10.0, 40.0)  # prior range of the camera's pitch (no gravity given)
    init_factor: int = 3                     # the first frame weighs this many times more particles (8 before;
                                             # 3: the same recognition on 80 development runs, seed 101, 7 runs
                                             # fixed, 7 lost, heading +1.9 +- 3.2 deg, a third less time)
    init_depth_band: tuple[float, float] = (0.35, 1.3)  # first depths log-uniform over this x the guess
                                             # (the flows'; [0.6, 1.4]: 12 fixed, 9 lost of 160 development runs,
                                             # the wall's baselink error +0.4 m; a share drawn about the guess:
                                             # no gain; docs/engine.md)
    init_keep: float = 0.25                  # ... and re-weighs the best share of them primitive by primitive
    noise_px: float = 1.0                    # assumed pixel noise of flow positions
    outlier_prob: float = 0.05
    weight_iterations: int = 2               # EM steps on the model points' mixture weights (docs/engine.md)
    open_memory_s: float = 1.0               # s: flows seen this recently mark the region obstacles leave open
                                             # (negative evidence there; < 0 turns it off)
    open_cell_px: float = 16.0               # px, the grid of that region
    weight_smoothing: float = 10.0           # pseudo-flows holding those weights towards the prior (issue 5;
                                             # 40: 80% against 90% on 60 development runs; 3: 6 fixed, 6 lost
                                             # of 160)
    n_eff_filter: float = 4.0                # tempering: a frame counts as at most this many flows (dev seeds)
                                             # (3: 11 fixed / 17 lost, 6: smoothed heading +5.7 deg; 240 runs)
    n_eff_recognition: float = 3.0           # ... for the recognition and the evidence (dev seeds; 6: 77%
                                             # against 90% on 60 development runs; on 240 runs of seeds
                                             # 101-103, 2: 14 fixed / 11 lost, 4.5: 8 / 18)
    recognise_velocities: bool = True        # recognition at a tracked pose scores velocities given positions
                                             # (each flow's, likelihood.velocity_log_likelihoods; 240
                                             # development runs, seeds 101-103: `full` 86.7 -> 91.2%, 19 fixed /
                                             # 8 lost, smoothed 90.4 -> 93.3%, 15 / 8; half the positions' term
                                             # taken off: 15 / 12 and 9 / 6; docs/engine.md)
    start_spread: float = 0.05               # start probability spread over all states
    prune: float = 1e-2                      # states below this times their primitive's best are not scored
                                             # (1e-4 before; 240 development runs, seeds 101-103: `full` 10
                                             # fixed / 10 lost, smoothed 8 / 3, heading +0.9 and -1.0 deg, the
                                             # recognition stage 14.2 -> 5.6 ms per frame; 0.05: smoothed
                                             # heading +8.7 deg; docs/engine.md, Speed)
    stream_prune: float = 1e-4               # ... and in the switching recursion of streams, where a primitive
                                             # entered mid-stream starts from its spread start distribution (1e-2
                                             # drops those states: 40 development streams, frame accuracy 0.648
                                             # -> 0.572 and 0.539 -> 0.416 behind a 30% wall)
    weigh_by_belief: bool = False            # streams: particles weighed under the belief's likeliest primitives
                                             # (True, before) or every primitive alike (False: the class belief
                                             # does not steer the pose; 40 development streams, seeds 101-102,
                                             # frame accuracy 0.40 -> 0.59 and 0.33 -> 0.49 behind a 30% wall;
                                             # docs/streams.md)
    weigh_classes: int = 3                   # by belief: at most this many primitives ...
    weigh_class_mass: float = 0.95           # ... the fewest that hold this much of the track's belief
    primitive_switch: float = 0.0            # per-frame probability of a primitive change (0: one per sequence)
    position_noise: float = 0.5              # m / sqrt(s), process noise of the base position (0.15 of issue 5:
                                             # 72% against 75%, base 0.54 against 0.49 m on 60 development runs:
                                             # a belief's wrong base velocity, a walk for a run, must be caught up)
    rotation_noise: float = 0.3              # rad / sqrt(s), of the base orientation (yaw when gravity is known)
    tilt_noise: float = 0.15                 # rad / sqrt(s), of the tilt when gravity is known
                                             # (0.05 could not follow the pelvis's own lean: with gravity and with the
                                             # floor, 480 development runs, seeds 124-125 at 10 and 40 deg,
                                             # full_smoothed 22 fixed / 5 lost, heading +0.9 deg on balance;
                                             # docs/engine.md, "Camera prior")
    floor_std: float = 0.05                  # m: the lowest body point's height about a known floor ...
    floor_flight: float = 0.2                # ... or, with this probability, in flight ...
    floor_flight_height: float = 0.8         # ... up to this height (m)
    refine_iterations: int = 2               # Gauss-Newton steps per M-step of recovery
    refine_position_std: float = 0.25        # m: least pose freedom recovery has around the filter's estimate
    refine_rotation_std: float = 0.3         # rad: recovery's rotation freedom around the filter's estimate
    recover_tracks: int = 1                  # tracks (most evidence first) refined by recovery each frame (2:
                                             # 73% against 72% on 60 development runs, at twice the cost; on
                                             # 240 runs of seeds 101-103, 13 fixed / 16 lost; 0: the wall's
                                             # baselink +0.09 m and gt_base's posture +11 mm for 14% less
                                             # time, 160 runs of seeds 136-137; docs/engine.md, Recovery)
    em_iterations: int = 3                   # re-assignments of flows to model points in recovery (issue 5;
                                             # 2: 10 fixed / 11 lost, smoothed 7 / 10 on 240 development runs)
    guide_fraction: float = 0.1              # share of a track's particles proposed around recovery's pose
    guide_rotation_std: float = 0.05         # rad, spread of those proposals (position: half the cloud's spread)
    track_turns: tuple[float, ...] = (90.0, 180.0, -90.0)   # tracks spawned at these turns of the leader
    twin_track: bool = True                  # and at the leader's depth-reflected twin
    class_tracks: bool = True                # these tracks once per primitive, each from the first frame weighed
                                             # under that primitive and believing only it (not in streams;
                                             # issue 21, 40 development runs per condition, seed 101: 87.5%
                                             # against 72.5%, 85 against 65 behind a wall at 40%)
    self_occlusion: bool = True              # the body hides itself in the likelihood (depth order)
    occlusion_radius: float = 1.0            # footprint of a point's patch, in patch radii
    occlusion_depth: float = 0.08            # m: a point must be this much nearer to cover another
    smoothing_frames: float = 2.0            # std (frames) of the offline estimate's trajectory smoother
    backward_pass: bool = True               # the offline estimate re-tracks the clip backwards from the causal
                                             # pass's final poses (engine.backward; else the causal leader smoothed)
    backward_live_only: bool = False         # ... only the primitives with a live track at the causal end
                                             # (half the backward pass's time; smoothed heading +4.1 deg,
                                             # 240 development runs: docs/engine.md, Speed)
    offline_both_passes: bool = True         # ... and decides the class by both passes' final tracks (else the
                                             # backward pass's alone; together 12 fixed, 5 lost of 160
                                             # development runs, smoothed heading 40.5 -> 30.7 deg)
    posterior_temperature: float = 3.8       # the class posterior's calibration (harness.engine.confidence) ...
    posterior_floor: float = 0.0229          # ... fitted by benchmarks/posterior_calibration.py on 160
                                             # development runs (seeds 101-102, recognition from velocities;
                                             # pooled ECE 0.062 raw, 0.139 under the values before (10.5, 0.074),
                                             # 0.012 fitted; held out on seed 103: 0.090, 0.152, 0.047; wrong
                                             # answers above 0.99: 44% raw, 0% fitted)
    min_spawn_ess: float = 5.0               # a track starts from the first frame's particles near it if they
                                             # hold this many effective particles, else from the lead's turned
    track_prune_nats: float = 30.0           # a track trailing the best by this much evidence is dropped (60:
                                             # 90% either way on 60 development runs)
    track_merge_deg: float = 30.0            # tracks closer than this in orientation ...
    track_merge_m: float = 0.3               # ... and this in position merge (the one with less evidence goes)
    reinject_every: int = 5                  # frames between re-injections of alternatives (0: none; track.py)
                                             # 6 runs fixed, 0 lost of 160 development runs (seeds 101-102)
    reinject_window: int = 10                # frames an alternative's path is replayed over
    reinject_classes: int = 3                # the best track of this many primitives (most evidence) gets them
                                             # (5: 2 fixed, 3 lost of 240 development runs, seeds 101-103)
    reinject_turns: tuple[float, ...] = (45.0, -45.0, 90.0, -90.0, 180.0)   # alternatives: turns (deg) ...
    reinject_twin: bool = True               # ... the twin ...
    reinject_depths: tuple[float, ...] = (0.85, 1.18)   # ... and depth scales of the track's path
    reinject_margin: float = 0.0             # nats a newcomer's score must beat its parent's by

    def __post_init__(self):
        positive = {"particles": self.particles, "model_points": self.model_points, "init_factor": self.init_factor,
                    "n_eff_filter": self.n_eff_filter, "n_eff_recognition": self.n_eff_recognition,
                    "noise_px": self.noise_px, "em_iterations": self.em_iterations}
        for name, value in positive.items():
            if not value > 0:
                raise EngineError(f"engine setting {name} must be positive, got {value}")
        for name in ("outlier_prob", "prune", "stream_prune"):
            value = getattr(self, name)
            if not 0 < value < 1:
                raise EngineError(f"engine setting {name} must be in (0, 1), got {value}")
        if not 0 <= self.primitive_switch < 1:
            raise EngineError(f"engine setting primitive_switch must be in [0, 1), got {self.primitive_switch}")
        if not 0 <= self.guide_fraction < 1:
            raise EngineError(f"engine setting guide_fraction must be in [0, 1), got {self.guide_fraction}")
        near, far = self.init_distance
        if not 0 < near < far:
            raise EngineError(f"engine setting init_distance must be [near, far] with 0 < near < far, "
                              f"got {list(self.init_distance)}")
        lo, hi = self.init_elevation
        if not -90 < lo <= hi < 90:
            raise EngineError(f"engine setting init_elevation must be [low, high] degrees within (-90, 90), "
                              f"got {list(self.init_elevation)}")
        if self.particles < self.n_tracks:
            raise EngineError(f"engine setting particles ({self.particles}) must be at least the number of "
                              f"tracks ({self.n_tracks})")
        _check_bounds(self)

    @property
    def n_tracks(self) -> int:
        """Tracks spawned per set (per primitive with ``class_tracks``)."""
        return 1 + len(self.track_turns) + int(self.twin_track)


# Sizes the engine allocates by: the first frame weighs particles x init_factor hypotheses against every
# model point, about 190 bytes per hypothesis-point (measured: 0.45 GB for 2000 x 8 x 150, 1.7 GB for
# 4000 x 8 x 300), so 2e7 of them is about 4 GB. The settings ran before only to fail with a MemoryError.
MAX_PARTICLES = 1_000_000
MAX_MODEL_POINTS = 100_000
MAX_HYPOTHESIS_POINTS = 20_000_000
MAX_ITERATIONS = 1000            # EM, weight and Gauss-Newton steps, recovered tracks, classes weighed
MAX_TRACK_TURNS = 16
MAX_DEPTH_SCALES = 5
# Settings that must be >= 0, > 0, or within [lo, hi] (None: open), beyond the checks above; each ran before
# with a meaningless result or failed deep inside a run (issue 23).
_AT_LEAST_ZERO = ("reinject_every", "reinject_margin", "model_seed", "weight_iterations", "refine_iterations", "recover_tracks", "smoothing_frames",
                  "weight_smoothing", "position_noise", "rotation_noise", "tilt_noise", "guide_rotation_std",
                  "occlusion_radius", "occlusion_depth", "min_spawn_ess", "track_merge_deg", "track_merge_m")
_ABOVE_ZERO = ("track_particles_max", "reinject_window", "reinject_classes", "open_cell_px", "posterior_temperature", "floor_std", "floor_flight_height",
               "refine_position_std", "refine_rotation_std", "track_prune_nats")
_WITHIN = {"init_keep": (0.0, 1.0, "(0, 1]"), "weigh_class_mass": (0.0, 1.0, "(0, 1]"), "start_spread": (None, 1.0, "[0, 1]"),
           "posterior_floor": (None, 1.0, "[0, 1)"), "floor_flight": (None, 1.0, "[0, 1)")}
_COUNTS = ("reinject_every", "reinject_window", "reinject_classes", "weight_iterations", "refine_iterations", "recover_tracks", "em_iterations", "weigh_classes",
           "init_factor")


def _check_bounds(cfg: TrackerConfig) -> None:
    """Finite numbers, signs, ranges and the sizes above (``TrackerConfig.__post_init__``)."""
    import math
    from dataclasses import fields

    for f in fields(cfg):
        value = getattr(cfg, f.name)
        items = value if isinstance(value, tuple) else (value,)
        for v in items:
            if isinstance(v, bool):
                continue
            if not isinstance(v, (int, float)) or (isinstance(v, float) and not math.isfinite(v)):
                raise EngineError(f"engine setting {f.name} must be a finite number, got {value!r}")
    for name in _AT_LEAST_ZERO:
        if not getattr(cfg, name) >= 0:
            raise EngineError(f"engine setting {name} must be >= 0, got {getattr(cfg, name)}")
    for name in _ABOVE_ZERO:
        if not getattr(cfg, name) > 0:
            raise EngineError(f"engine setting {name} must be positive, got {getattr(cfg, name)}")
    for name, (lo, hi, text) in _WITHIN.items():
        v = getattr(cfg, name)
        low_ok = v >= 0 if lo is None else v > lo
        high_ok = v < hi if text.endswith(")") else v <= hi
        if not (low_ok and high_ok):
            raise EngineError(f"engine setting {name} must be in {text}, got {v}")
    if cfg.weigh_classes < 1:
        raise EngineError(f"engine setting weigh_classes must be at least 1, got {cfg.weigh_classes}")
    for name in _COUNTS:
        if getattr(cfg, name) > MAX_ITERATIONS:
            raise EngineError(f"engine setting {name} must be at most {MAX_ITERATIONS}, got {getattr(cfg, name)}")
    if cfg.particles > MAX_PARTICLES:
        raise EngineError(f"engine setting particles must be at most {MAX_PARTICLES}, got {cfg.particles}")
    if cfg.model_points > MAX_MODEL_POINTS:
        raise EngineError(f"engine setting model_points must be at most {MAX_MODEL_POINTS}, got {cfg.model_points}")
    if len(cfg.track_turns) > MAX_TRACK_TURNS:
        raise EngineError(f"engine setting track_turns lists {len(cfg.track_turns)} turns, at most "
                          f"{MAX_TRACK_TURNS}")
    if len(cfg.init_depth_band) != 2 or not 0.1 <= cfg.init_depth_band[0] < cfg.init_depth_band[1] <= 10.0:
        raise EngineError(f"engine setting init_depth_band must be [near, far] scales of the depth guess with "
                          f"0.1 <= near < far <= 10, got {list(cfg.init_depth_band)}")
    if len(cfg.reinject_turns) > MAX_TRACK_TURNS or len(cfg.reinject_depths) > MAX_DEPTH_SCALES or not all(
            0.2 <= s <= 5.0 for s in cfg.reinject_depths):
        raise EngineError(f"engine settings reinject_turns and reinject_depths list at most {MAX_TRACK_TURNS} turns "
                          f"and {MAX_DEPTH_SCALES} depth scales within [0.2, 5], got {list(cfg.reinject_turns)} and "
                          f"{list(cfg.reinject_depths)}")
    if round(cfg.init_keep * cfg.particles * cfg.init_factor) < 1:
        raise EngineError(f"engine setting init_keep ({cfg.init_keep}) keeps no particle of the first frame's "
                          f"{cfg.particles * cfg.init_factor}")
    work = cfg.particles * cfg.init_factor * cfg.model_points
    if work > MAX_HYPOTHESIS_POINTS:
        raise EngineError(f"engine setting particles ({cfg.particles}) x init_factor ({cfg.init_factor}) x "
                          f"model_points ({cfg.model_points}) = {work:.3g} hypothesis-points on the first frame, "
                          f"more than {MAX_HYPOTHESIS_POINTS:.0e} (about 190 bytes each)")


def settings_from_strings(items: list[str]) -> dict:
    """``["key=value", ...]`` (a command line's engine settings) as TrackerConfig keyword arguments, each value
    typed by its field's default; raises EngineError naming an unknown key or a malformed value."""
    default, out = TrackerConfig(), {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not hasattr(default, key):
            raise EngineError(f"engine setting {item!r}: expected KEY=VALUE with a TrackerConfig field as KEY")
        kind = type(getattr(default, key))
        try:
            if kind is bool:
                out[key] = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False}[value.lower()]
            elif kind is tuple:
                out[key] = tuple(float(v) for v in value.split(",") if v)
            else:
                out[key] = kind(value)
        except (KeyError, ValueError):
            raise EngineError(f"engine setting {key}: cannot read {value!r} as {kind.__name__}") from None
    return out

