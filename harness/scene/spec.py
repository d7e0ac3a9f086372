"""What one camera sees of a performance: the scene's parameters as frozen, validated dataclasses.

These types are the one schema of the scene: the evaluation's scenario sections ``markers``, ``camera``,
``occluders``, ``observation`` and ``subject`` are generated from them (``harness.evaluation.scenario``), and
the schema table in ``docs/evaluation.md`` is generated from their field metadata (unit, allowed values,
meaning; a test checks it). Every field is checked when the object is built; a bad value raises
``SceneError`` naming the field and the value (``.key``, ``.value`` and ``.why`` carry the parts). Units:
metres, degrees (angles a person types), pixels, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from harness.errors import HarnessError
from harness.pinhole import MAX_IMAGE_SIDE

CAMERA_MOTIONS = ("static", "orbit", "follow")
OBSERVATION_MODES = ("geometric", "rendered", "video")
CAMERA_PRIORS = ("none", "gravity", "floor")
OCCLUDER_GEOM_TYPES = ("box", "cylinder", "capsule")
MAX_OCCLUSION_AMOUNT = 0.9      # a preset cannot be calibrated to hide everything: some lines of sight pass
MAX_OUTLIERS = 10.0             # outlier flows per visible flow
MAX_LIMB_SCALE = 0.15           # std of the per-segment length factor (factors clipped at +-3 std)
SUBJECT_SCALE_RANGE = (0.5, 1.5)
# Sizes a scene allocates by (markers x frames arrays, a rendered image) and distances beyond any room: each
# ran before only to fail with a MemoryError or overflow (issue 23).
MAX_MARKERS = 10_000
MAX_DISTANCE_M = 1000.0         # camera distance, look-at height, obstacle centres
MAX_OBSTACLE_M = 100.0          # obstacle half-sizes
MAX_FOVY_DEG = 170.0            # a wider pinhole is degenerate (and no lens)
# Presets are registered in harness.scene.occluders; listed here so that a spec can be validated
# without building any geometry. A test checks that the two lists agree.
OCCLUDER_PRESETS = ("none", "low_wall", "pillar", "boxes")


class SceneError(HarnessError):
    """Scene parameters that cannot describe a camera view (names the field and the value)."""

    def __init__(self, message: str, key: str | None = None, value=None, why: str | None = None):
        super().__init__(message)
        self.key, self.value, self.why = key, value, why


def _require(ok: bool, name: str, value, why: str) -> None:
    if not ok:
        raise SceneError(f"{name}={value!r}: {why}", name, value, why)


def _finite(name: str, value) -> float:
    _require(isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value),
             name, value, "must be a finite number")
    return float(value)


def _integer(name: str, value) -> int:
    _require(isinstance(value, int) and not isinstance(value, bool), name, value, "must be an integer")
    return int(value)


def _param(default, unit: str, values: str, meaning: str, **kw):
    """A field with the metadata the documentation and the scenario schema are generated from."""
    if isinstance(default, (list, dict)):
        raise TypeError("mutable default")
    return field(default=default, metadata={"unit": unit, "values": values, "meaning": meaning}, **kw)


@dataclass(frozen=True)
class MarkerSpec:
    """``count`` unlabeled surface markers, placed area-uniformly by ``seed``."""

    count: int = _param(100, "", f"int in [1, {MAX_MARKERS}]", "random surface sites on the body (unlabeled features)")
    seed: int = _param(0, "", "int >= 0", "placement seed")

    def __post_init__(self):
        _require(_integer("markers.count", self.count) >= 1, "markers.count", self.count,
                 "at least one marker is needed")
        _require(self.count <= MAX_MARKERS, "markers.count", self.count, f"at most {MAX_MARKERS} markers")
        _require(_integer("markers.seed", self.seed) >= 0, "markers.seed", self.seed, "must be >= 0")


@dataclass(frozen=True)
class CameraSpec:
    """Camera placement relative to the subject, and its pinhole (docs/scene.md, "Frames and camera placement").

    The look-at point is the mean of the subject's base xy over the motion, at ``look_at_height``.
    """

    distance: float = _param(4.0, "m", f"(0, {MAX_DISTANCE_M:g}]", "from the look-at point")
    azimuth: float = _param(0.0, "deg", "finite", "about world z from the subject's initial heading (0: in front, "
                                                  "seeing the face; 90: on its left)")
    elevation: float = _param(10.0, "deg", "(-90, 90)", "above the look-at point (positive looks down)")
    fovy: float = _param(45.0, "deg", f"(0, {MAX_FOVY_DEG:g}]", "vertical field of view")
    width: int = _param(640, "px", f"int in [16, {MAX_IMAGE_SIDE}]", "image width")
    height: int = _param(480, "px", f"int in [16, {MAX_IMAGE_SIDE}]", "image height")
    look_at_height: float = _param(0.9, "m", f"[-{MAX_DISTANCE_M:g}, {MAX_DISTANCE_M:g}]",
                                   "height of the look-at point above the floor (0.9: the middle of the 1.765 m "
                                   "standing body)")
    motion: str = _param("static", "", ", ".join(CAMERA_MOTIONS),
                         "static; orbit: circles the look-at point at orbit_rate; follow: translates with the "
                         "subject's base xy, orientation fixed (a robot following the subject)")
    orbit_rate: float = _param(0.0, "deg/s", "finite", "orbit speed (motion: orbit)")

    def __post_init__(self):
        _require(_finite("camera.distance", self.distance) > 0.0, "camera.distance", self.distance,
                 "must be positive (metres)")
        _require(self.distance <= MAX_DISTANCE_M, "camera.distance", self.distance,
                 f"must be at most {MAX_DISTANCE_M:g} m")
        _finite("camera.azimuth", self.azimuth)
        _require(abs(_finite("camera.elevation", self.elevation)) < 90.0, "camera.elevation", self.elevation,
                 "must be in (-90, 90) degrees")
        _require(0.0 < _finite("camera.fovy", self.fovy) <= MAX_FOVY_DEG, "camera.fovy", self.fovy,
                 f"must be in (0, {MAX_FOVY_DEG:g}] degrees")
        for name in ("width", "height"):
            value = getattr(self, name)
            _require(16 <= _integer(f"camera.{name}", value) <= MAX_IMAGE_SIDE, f"camera.{name}", value,
                     f"must be in [16, {MAX_IMAGE_SIDE}] pixels")
        _require(abs(_finite("camera.look_at_height", self.look_at_height)) <= MAX_DISTANCE_M,
                 "camera.look_at_height", self.look_at_height, f"must be within +-{MAX_DISTANCE_M:g} m")
        _require(self.motion in CAMERA_MOTIONS, "camera.motion", self.motion,
                 f"must be one of {', '.join(CAMERA_MOTIONS)}")
        _finite("camera.orbit_rate", self.orbit_rate)


@dataclass(frozen=True)
class OccluderGeom:
    """One obstacle given by hand, upright (its axis along world z), in the subject's start frame: origin at
    the subject's base xy at the first frame, on the floor; x along its initial heading, y to its left, z up.

    size follows MuJoCo: box ``[half x, half y, half z]``; cylinder ``[radius, half height]``; capsule
    ``[radius, half length of the cylindrical part]`` (its total height is ``2 (radius + half length)``).
    """

    type: str = _param("box", "", ", ".join(OCCLUDER_GEOM_TYPES), "geom type")
    pos: tuple[float, float, float] = _param((1.5, 0.0, 0.5), "m", f"3 numbers within +-{MAX_DISTANCE_M:g}",
                                             "centre, subject's start frame")
    size: tuple[float, ...] = _param((0.5, 0.5, 0.5), "m",
                                     f"3 (box) or 2 (cylinder, capsule) numbers in (0, {MAX_OBSTACLE_M:g}]",
                                     "half-sizes as in MuJoCo")
    yaw: float = _param(0.0, "deg", "finite", "rotation about z from the subject's initial heading")

    def __post_init__(self):
        _require(self.type in OCCLUDER_GEOM_TYPES, "type", self.type,
                 f"must be one of {', '.join(OCCLUDER_GEOM_TYPES)}")
        _require(isinstance(self.pos, (tuple, list)) and len(self.pos) == 3, "pos", self.pos,
                 "must be 3 numbers [x, y, z] (metres)")
        for v in self.pos:
            _require(abs(_finite("pos", v)) <= MAX_DISTANCE_M, "pos", self.pos,
                     f"every coordinate must be within +-{MAX_DISTANCE_M:g} m")
        n = 3 if self.type == "box" else 2
        _require(isinstance(self.size, (tuple, list)) and len(self.size) == n, "size", self.size,
                 f"a {self.type} takes {n} numbers")
        for v in self.size:
            _require(_finite("size", v) > 0.0, "size", self.size, "every size must be positive (metres)")
            _require(v <= MAX_OBSTACLE_M, "size", self.size, f"every half-size must be at most {MAX_OBSTACLE_M:g} m")
        _finite("yaw", self.yaw)


@dataclass(frozen=True)
class OccluderSpec:
    """Obstacles between camera and subject: a named preset sized to hide ``amount`` of the subject, or
    obstacles given by hand (``geoms``)."""

    preset: str = _param("none", "", ", ".join(OCCLUDER_PRESETS), "obstacle layout across the line of sight "
                                                                   "(docs/scene.md)")
    amount: float = _param(0.0, "fraction", f"[0, {MAX_OCCLUSION_AMOUNT}]",
                           "pooled fraction of in-view marker-frames the preset is sized to hide (0: no obstacle)")
    seed: int = _param(0, "", "int >= 0", "layout seed of the seeded presets (pillar side, crates)")
    geoms: tuple[OccluderGeom, ...] = _param((), "", "list of {type, pos, size, yaw}",
                                             "obstacles given by hand instead of a preset (preset none)")

    def __post_init__(self):
        _require(self.preset in OCCLUDER_PRESETS, "occluders.preset", self.preset,
                 f"unknown preset; presets: {', '.join(OCCLUDER_PRESETS)}")
        _require(0.0 <= _finite("occluders.amount", self.amount) <= MAX_OCCLUSION_AMOUNT, "occluders.amount",
                 self.amount, f"must be in [0, {MAX_OCCLUSION_AMOUNT}]")
        _require(_integer("occluders.seed", self.seed) >= 0, "occluders.seed", self.seed, "must be >= 0")
        _require(isinstance(self.geoms, tuple) and all(isinstance(g, OccluderGeom) for g in self.geoms),
                 "occluders.geoms", self.geoms, "must be a tuple of OccluderGeom")
        _require(not self.geoms or (self.preset == "none" and self.amount == 0.0), "occluders.geoms",
                 len(self.geoms), "obstacles given by hand replace a preset: set preset none and amount 0")
        _require(self.preset != "none" or self.amount == 0.0, "occluders.amount", self.amount,
                 "preset 'none' hides nothing; choose a preset to request occlusion")


@dataclass(frozen=True)
class ObservationSpec:
    """How flows are measured (docs/scene.md, "Flows")."""

    mode: str = _param("geometric", "", ", ".join(OBSERVATION_MODES),
                       "projected markers; dots detected in MuJoCo images and tracked by Lucas-Kanade; or the body "
                       "rendered in cloth and its flows found by track-video's pipeline (docs/video.md; static "
                       "camera)")
    noise_px: float = _param(1.0, "px", ">= 0", "std of the Gaussian noise on each measured position "
                                                "(geometric mode)")
    dropout: float = _param(0.0, "probability", "[0, 1)", "a visible flow is dropped")
    outliers: float = _param(0.0, "per visible flow", f"[0, {MAX_OUTLIERS:g}]",
                             "round(outliers x visible count) outlier flows are added per frame (uniform in the "
                             "image, velocities uniform in +-300 px/s)")
    camera_prior: str = _param("none", "", ", ".join(CAMERA_PRIORS),
                               "what the camera knows of itself and writes into the observation: nothing (the "
                               "paper's setting), its tilt (gravity in the camera frame, as from an IMU), or "
                               "gravity and its height above the floor")

    def __post_init__(self):
        _require(self.mode in OBSERVATION_MODES, "observation.mode", self.mode,
                 f"must be one of {', '.join(OBSERVATION_MODES)}")
        _require(_finite("observation.noise_px", self.noise_px) >= 0.0, "observation.noise_px", self.noise_px,
                 "must be >= 0 (pixels)")
        _require(0.0 <= _finite("observation.dropout", self.dropout) < 1.0, "observation.dropout",
                 self.dropout, "must be in [0, 1)")
        _require(0.0 <= _finite("observation.outliers", self.outliers) <= MAX_OUTLIERS, "observation.outliers",
                 self.outliers, f"must be in [0, {MAX_OUTLIERS:g}] (outliers per visible flow)")
        _require(self.camera_prior in CAMERA_PRIORS, "observation.camera_prior", self.camera_prior,
                 f"must be one of {', '.join(CAMERA_PRIORS)}")


@dataclass(frozen=True)
class SubjectSpec:
    """The observed person against the engine's nominal body (docs/evaluation.md, "Subject mismatch").

    The observed humanoid is the nominal one scaled uniformly by ``scale``, each segment's length further
    multiplied by ``1 + limb_scale * N(0, 1)`` (clipped at 3 std; drawn per segment from ``seed``, one factor
    for a left/right pair). The engine and its database keep the nominal body.
    """

    scale: float = _param(1.0, "", f"[{SUBJECT_SCALE_RANGE[0]}, {SUBJECT_SCALE_RANGE[1]}]",
                          "uniform scale of the observed humanoid (1: the nominal 1.765 m body)")
    limb_scale: float = _param(0.0, "std", f"[0, {MAX_LIMB_SCALE}]", "per-segment length jitter")
    seed: int = _param(0, "", "int >= 0", "draw of the segment factors")

    def __post_init__(self):
        lo, hi = SUBJECT_SCALE_RANGE
        _require(lo <= _finite("subject.scale", self.scale) <= hi, "subject.scale", self.scale,
                 f"must be in [{lo}, {hi}]")
        _require(0.0 <= _finite("subject.limb_scale", self.limb_scale) <= MAX_LIMB_SCALE, "subject.limb_scale",
                 self.limb_scale, f"must be in [0, {MAX_LIMB_SCALE}]")
        _require(_integer("subject.seed", self.seed) >= 0, "subject.seed", self.seed, "must be >= 0")

    @property
    def nominal(self) -> bool:
        return self.scale == 1.0 and self.limb_scale == 0.0


@dataclass(frozen=True)
class SceneSpec:
    """The whole scene: markers, camera, occluders, observation model, and the observed subject."""

    markers: MarkerSpec = field(default_factory=MarkerSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    occluders: OccluderSpec = field(default_factory=OccluderSpec)
    observation: ObservationSpec = field(default_factory=ObservationSpec)
    subject: SubjectSpec = field(default_factory=SubjectSpec)

    def __post_init__(self):
        for name, kind in (("markers", MarkerSpec), ("camera", CameraSpec), ("occluders", OccluderSpec),
                           ("observation", ObservationSpec), ("subject", SubjectSpec)):
            value = getattr(self, name)
            _require(isinstance(value, kind), name, type(value).__name__, f"must be a {kind.__name__}")
        # Background subtraction learns one background: the camera must stand still.
        _require(self.observation.mode != "video" or self.camera.motion == "static", "camera.motion",
                 self.camera.motion, "observation.mode 'video' finds people by background subtraction and needs a "
                 "static camera")
