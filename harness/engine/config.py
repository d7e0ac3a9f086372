"""The engine's settings: one frozen section per stage, each field declared once with its default, unit, bounds
and meaning (``harness.settings``). A stage receives its own section only; ``TrackerConfig`` holds them all and
checks the rules between sections. Where each value came from: ``docs/settings.md``."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from harness.errors import EngineError
from harness.settings import SectionBase, from_sections, parse_assignments, setting

# The first frame weighs particles x spawn.factor hypotheses against every model point, about 190 bytes per
# hypothesis-point (0.45 GB for 2000 x 8 x 150): 2e7 of them is about 4 GB.
MAX_HYPOTHESIS_POINTS = 20_000_000
COUNT = "[0, 1000]"         # steps, tracks, classes, frames: beyond is a typo, not a setting


class _Section(SectionBase, label="engine setting", error=EngineError):
    pass


@dataclass(frozen=True)
class ModelSettings(_Section, name="model"):
    """The engine's own body-surface sample (``EngineModel.build``)."""
    points: int = setting(120, "", "[1, 100000]", "model points, spread evenly over the body", was="model_points")
    seed: int = setting(7, "", ">= 0", "their sample's seed, independent of the markers", was="model_seed")


@dataclass(frozen=True)
class SpawnSettings(_Section, name="spawn"):
    """The first frame with flows: a wide cloud over the coarse prior, and the tracks spawned from it."""
    distance: tuple[float, float] = setting((2.0, 8.0), "m", "> 0", "prior range of the subject's distance",
                                            size=2, ordered="<", was="init_distance")
    elevation: tuple[float, float] = setting((-10.0, 40.0), "deg", "(-90, 90)", "prior range of the camera's pitch "
                                             "(no gravity given)", size=2, ordered="<=", was="init_elevation")
    factor: int = setting(3, "", "[1, 1000]", "the first frame weighs this many times the particles", was="init_factor")
    depth_band: tuple[float, float] = setting((0.35, 1.3), "", "[0.1, 10]", "first depths log-uniform over this "
                                              "times the flows' guess", size=2, ordered="<", was="init_depth_band")
    keep: float = setting(0.25, "", "(0, 1]", "best share of that cloud re-weighed per primitive", was="init_keep")
    min_ess: float = setting(5.0, "", ">= 0", "effective particles near a track to start it (else the lead's, turned)",
                             was="min_spawn_ess")
    turns: tuple[float, ...] = setting((90.0, 180.0, -90.0), "deg", "", "tracks at these turns of the lead",
                                       size=(0, 16), was="track_turns")
    twin: bool = setting(True, "", "", "and a track at the lead's depth-reflected twin", was="twin_track")
    per_class: bool = setting(True, "", "", "a set per primitive believing only it (not streams)", was="class_tracks")

    @property
    def n_tracks(self) -> int:
        """Tracks spawned per set (per primitive with ``per_class``)."""
        return 1 + len(self.turns) + int(self.twin)


@dataclass(frozen=True)
class LikelihoodSettings(_Section, name="likelihood"):
    """How a frame's unlabeled flows are scored under projected distributions (``Scorer``, ``Frames``)."""
    noise_px: float = setting(1.0, "px", "> 0", "assumed pixel noise of flow positions")
    outlier_prob: float = setting(0.05, "", "(0, 1)", "share of flows from the uniform outlier term")
    weight_iterations: int = setting(2, "", COUNT, "EM steps on the model points' mixture weights")
    weight_smoothing: float = setting(10.0, "flows", ">= 0", "pseudo-flows holding those weights to the prior")
    n_eff_filter: float = setting(4.0, "flows", "> 0", "tempering: a frame counts as this many flows for the poses")
    n_eff_recognition: float = setting(3.0, "flows", "> 0", "... for recognition and the evidence")
    recognise_velocities: bool = setting(True, "", "", "at a tracked pose, recognise velocities given positions")
    self_occlusion: bool = setting(True, "", "", "the body hides itself in the likelihood (depth order)")
    occlusion_radius: float = setting(1.0, "patch radii", ">= 0", "footprint of a point's patch")
    occlusion_depth: float = setting(0.08, "m", ">= 0", "a point must be this much nearer to cover another")
    open_memory_s: float = setting(1.0, "s", "", "flows this recent mark the open region (negative evidence; < 0: off)")
    open_cell_px: float = setting(16.0, "px", "> 0", "the grid of that region")
    floor_std: float = setting(0.05, "m", "> 0", "known floor: the lowest body point's height about it ...")
    floor_flight: float = setting(0.2, "", "[0, 1)", "... or, with this probability, in flight ...")
    floor_flight_height: float = setting(0.8, "m", "> 0", "... up to this height")


@dataclass(frozen=True)
class BeliefSettings(_Section, name="belief"):
    """Each track's forward recursion over primitives and states, and the class posterior's calibration."""
    start_spread: float = setting(0.05, "", "[0, 1]", "start probability spread over all states")
    prune: float = setting(1e-2, "", "(0, 1)", "states below this times their primitive's best are not scored")
    stream_prune: float = setting(1e-4, "", "(0, 1)", "... in the switching recursion of streams")
    primitive_switch: float = setting(0.0, "per frame", "[0, 1)", "probability of a primitive change (0: one)")
    posterior_temperature: float = setting(3.8, "", "> 0", "the class posterior's calibration: temperature ...")
    posterior_floor: float = setting(0.0229, "", "[0, 1)", "... and floor (harness.engine.confidence)")
    unknown_bias: float = setting(0.0, "nats", "", "... and the background class's log prior odds (unknown)")


@dataclass(frozen=True)
class MotionSettings(_Section, name="motion"):
    """How particles move between frames: process noise, and proposals around recovery's pose."""
    position_noise: float = setting(0.5, "m/sqrt(s)", ">= 0", "process noise of the base position")
    rotation_noise: float = setting(0.3, "rad/sqrt(s)", ">= 0", "... of its orientation (yaw when gravity is known)")
    tilt_noise: float = setting(0.15, "rad/sqrt(s)", ">= 0", "... of its tilt when gravity is known")
    guide_fraction: float = setting(0.1, "", "[0, 1)", "share of a track's particles proposed at recovery's pose")
    guide_rotation_std: float = setting(0.05, "rad", ">= 0", "their spread (position: half the cloud's)")


@dataclass(frozen=True)
class TracksSettings(_Section, name="tracks"):
    """The tracks' particle budget, what their particles are weighed under, and which tracks go on."""
    particles: int = setting(500, "", "[1, 1000000]", "particles in total over all tracks")
    particles_max: int = setting(50, "", ">= 1", "... and at most this many per track", was="track_particles_max")
    prune_nats: float = setting(30.0, "nats", "> 0", "a track this far behind is dropped", was="track_prune_nats")
    merge_deg: float = setting(30.0, "deg", ">= 0", "tracks this close in orientation ...", was="track_merge_deg")
    merge_m: float = setting(0.3, "m", ">= 0", "... and position merge (the weaker goes)", was="track_merge_m")
    weigh_by_belief: bool = setting(False, "", "", "streams: weigh under the likeliest primitives (else all alike)")
    weigh_classes: int = setting(3, "", "[1, 1000]", "by belief: at most this many primitives ...")
    weigh_class_mass: float = setting(0.95, "", "(0, 1]", "... the fewest that hold this much of the belief")


@dataclass(frozen=True)
class ReinjectionSettings(_Section, name="reinjection"):
    """Alternatives of the leading primitives' paths (``ParticleTracks.reinject``)."""
    every: int = setting(5, "frames", COUNT, "frames between re-injections (0: none)", was="reinject_every")
    window: int = setting(10, "frames", "[1, 1000]", "frames an alternative is replayed over", was="reinject_window")
    classes: int = setting(3, "", "[1, 1000]", "the best track of this many primitives", was="reinject_classes")
    turns: tuple[float, ...] = setting((45.0, -45.0, 90.0, -90.0, 180.0), "deg", "", "alternatives: turns ...",
                                       size=(0, 16), was="reinject_turns")
    twin: bool = setting(True, "", "", "... the twin ...", was="reinject_twin")
    depths: tuple[float, ...] = setting((0.85, 1.18), "", "[0.2, 5]", "... and depth scales of the path",
                                        size=(0, 5), was="reinject_depths")
    margin: float = setting(0.0, "nats", ">= 0", "a newcomer must beat its parent by this", was="reinject_margin")


@dataclass(frozen=True)
class RecoverySettings(_Section, name="recovery"):
    """Angles and pose refined against the flows under the HMM prior (``recovery.recover``)."""
    tracks: int = setting(1, "", COUNT, "tracks (most evidence first) refined each frame", was="recover_tracks")
    em_iterations: int = setting(3, "", "[1, 1000]", "re-assignments of flows to model points")
    refine_iterations: int = setting(2, "", COUNT, "Gauss-Newton steps per M-step")
    position_std: float = setting(0.25, "m", "> 0", "least position room about the filter", was="refine_position_std")
    rotation_std: float = setting(0.3, "rad", "> 0", "rotation freedom about it", was="refine_rotation_std")


@dataclass(frozen=True)
class BottomUpSettings(_Section, name="bottomup"):
    """The bottom-up posture (``bottom_up``): a learned estimate from each window of flows, up to the twin, used
    as the first frame's pose prior, as re-injection's alternatives and as recovery's posture prior."""
    enabled: bool = setting(True, "", "", "estimate the posture from each window of flows (the shipped model)")
    spawn_share: float = setting(0.5, "", "[0, 1]", "first frame's pose prior: this share about the estimate's "
                                 "two modes, the rest the coarse prior")
    spawn_rotation_std: float = setting(0.15, "rad", ">= 0", "least rotation spread of those draws")
    spawn_depth_std: float = setting(0.1, "", ">= 0", "least spread of their depth's log")
    weigh_posture: bool = setting(False, "", "", "a track's particles are weighed at its belief fused with the "
                                  "estimate's posture (its nearer mode)")
    reinject: bool = setting(True, "", "", "re-injection also tries the turn and depth to the estimate's modes")
    recovery_weight: float = setting(1.0, "", ">= 0", "recovery's prior: the estimate's posture precision times "
                                     "this, fused with the belief's (0: the belief's alone)")


@dataclass(frozen=True)
class OfflineSettings(_Section, name="offline"):
    """The offline (hindsight) estimate: the backward pass and the trajectory smoother."""
    smoothing_frames: float = setting(2.0, "frames", ">= 0", "std of the offline trajectory smoother")
    backward_pass: bool = setting(True, "", "", "re-track backwards from the final poses (else smooth the leader)")
    backward_live_only: bool = setting(False, "", "", "... only for the primitives live at the end")
    both_passes: bool = setting(True, "", "", "... and decide the class by both passes", was="offline_both_passes")


@dataclass(frozen=True)
class TrackerConfig:
    """Every engine setting, by section (``engine.<section>.<field>`` in a scenario)."""

    model: ModelSettings = field(default_factory=ModelSettings)
    spawn: SpawnSettings = field(default_factory=SpawnSettings)
    likelihood: LikelihoodSettings = field(default_factory=LikelihoodSettings)
    belief: BeliefSettings = field(default_factory=BeliefSettings)
    motion: MotionSettings = field(default_factory=MotionSettings)
    tracks: TracksSettings = field(default_factory=TracksSettings)
    reinjection: ReinjectionSettings = field(default_factory=ReinjectionSettings)
    recovery: RecoverySettings = field(default_factory=RecoverySettings)
    bottomup: BottomUpSettings = field(default_factory=BottomUpSettings)
    offline: OfflineSettings = field(default_factory=OfflineSettings)

    def __post_init__(self):
        n, spawn = self.tracks.particles, self.spawn
        if n < spawn.n_tracks:
            raise EngineError(f"engine setting tracks.particles ({n}) must be at least the tracks spawned "
                              f"({spawn.n_tracks})")
        if round(spawn.keep * n * spawn.factor) < 1:
            raise EngineError(f"engine setting spawn.keep ({spawn.keep}) keeps none of the first frame's "
                              f"{n * spawn.factor} particles")
        if n * spawn.factor * self.model.points > MAX_HYPOTHESIS_POINTS:
            raise EngineError(f"engine settings tracks.particles ({n}) x spawn.factor ({spawn.factor}) x model.points "
                              f"({self.model.points}) = {n * spawn.factor * self.model.points:.3g} hypothesis-points "
                              f"on the first frame, more than {MAX_HYPOTHESIS_POINTS:.0e} (about 190 bytes each)")

    @classmethod
    def from_dict(cls, values: dict) -> TrackerConfig:
        """From ``{section: {field: value}}`` or ``{"section.field": value}``; a former flat name is refused with
        its new place."""
        return from_sections(cls, values, EngineError, "engine setting")

    def with_values(self, values: dict) -> TrackerConfig:
        """A copy with ``{section: {field: value}}`` replaced (``settings_from_strings``' output)."""
        return replace(self, **{s: replace(getattr(self, s), **v) for s, v in values.items()})


def settings_from_strings(items: list[str]) -> dict:
    """``["section.field=value", ...]`` (a command line's engine settings) for ``TrackerConfig.with_values``."""
    return parse_assignments(TrackerConfig, items, EngineError, "engine setting")
