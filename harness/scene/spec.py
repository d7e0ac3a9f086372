"""What one camera sees of a performance: the scene's parameters as frozen, validated dataclasses.

Every field is checked when the object is built; a bad value raises ``SceneError`` naming the field and
the value. Units: metres, degrees (angles a person types), pixels, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from harness.errors import HarnessError

CAMERA_MOTIONS = ("static", "orbit", "follow")
OBSERVATION_MODES = ("geometric", "rendered")
CAMERA_PRIORS = ("none", "gravity", "floor")
MAX_OCCLUSION_AMOUNT = 0.9
# Presets are registered in harness.scene.occluders; listed here so that a spec can be validated
# without building any geometry. A test checks that the two lists agree.
OCCLUDER_PRESETS = ("none", "low_wall", "pillar", "boxes")


class SceneError(HarnessError):
    """Scene parameters that cannot describe a camera view (names the field and the value)."""


def _require(ok: bool, name: str, value, why: str) -> None:
    if not ok:
        raise SceneError(f"{name}={value!r}: {why}")


def _finite(name: str, value) -> float:
    _require(isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value),
             name, value, "must be a finite number")
    return float(value)


def _integer(name: str, value) -> int:
    _require(isinstance(value, int) and not isinstance(value, bool), name, value, "must be an integer")
    return int(value)


@dataclass(frozen=True)
class MarkerSpec:
    """``count`` unlabeled surface markers, placed area-uniformly by ``seed``."""

    count: int = 100
    seed: int = 0

    def __post_init__(self):
        _require(_integer("markers.count", self.count) >= 1, "markers.count", self.count,
                 "at least one marker is needed")
        _require(_integer("markers.seed", self.seed) >= 0, "markers.seed", self.seed, "must be >= 0")


@dataclass(frozen=True)
class CameraSpec:
    """Camera placement relative to the subject, and its pinhole.

    distance: metres from the look-at point. azimuth: degrees about world z from the subject's initial
    heading (0 = in front, seeing the face; 90 = on its left). elevation: degrees, positive = above the
    look-at point, looking down. fovy: vertical field of view, degrees. width, height: pixels.
    look_at_height: metres above the floor. motion: "static", "orbit" (circles the look-at point at
    ``orbit_rate`` deg/s) or "follow" (translates with the subject's base xy).
    """

    distance: float = 4.0
    azimuth: float = 0.0
    elevation: float = 10.0
    fovy: float = 45.0
    width: int = 640
    height: int = 480
    look_at_height: float = 1.0
    motion: str = "static"
    orbit_rate: float = 0.0

    def __post_init__(self):
        _require(_finite("camera.distance", self.distance) > 0.0, "camera.distance", self.distance,
                 "must be positive (metres)")
        _finite("camera.azimuth", self.azimuth)
        _require(abs(_finite("camera.elevation", self.elevation)) < 90.0, "camera.elevation", self.elevation,
                 "must be in (-90, 90) degrees")
        _require(0.0 < _finite("camera.fovy", self.fovy) < 180.0, "camera.fovy", self.fovy,
                 "must be in (0, 180) degrees")
        _require(_integer("camera.width", self.width) > 0, "camera.width", self.width, "must be positive (pixels)")
        _require(_integer("camera.height", self.height) > 0, "camera.height", self.height,
                 "must be positive (pixels)")
        _finite("camera.look_at_height", self.look_at_height)
        _require(self.motion in CAMERA_MOTIONS, "camera.motion", self.motion,
                 f"must be one of {', '.join(CAMERA_MOTIONS)}")
        _finite("camera.orbit_rate", self.orbit_rate)


@dataclass(frozen=True)
class OccluderSpec:
    """Obstacles between camera and subject: a named preset hiding ``amount`` (0..0.9) of the subject."""

    preset: str = "none"
    amount: float = 0.0
    seed: int = 0

    def __post_init__(self):
        _require(self.preset in OCCLUDER_PRESETS, "occluders.preset", self.preset,
                 f"unknown preset; presets: {', '.join(OCCLUDER_PRESETS)}")
        _require(0.0 <= _finite("occluders.amount", self.amount) <= MAX_OCCLUSION_AMOUNT, "occluders.amount",
                 self.amount, f"must be in [0, {MAX_OCCLUSION_AMOUNT}]")
        _require(self.preset != "none" or self.amount == 0.0, "occluders.amount", self.amount,
                 "preset 'none' hides nothing; choose a preset to request occlusion")
        _require(_integer("occluders.seed", self.seed) >= 0, "occluders.seed", self.seed, "must be >= 0")


@dataclass(frozen=True)
class ObservationSpec:
    """How flows are measured.

    mode: "geometric" (projected markers) or "rendered" (dots detected in MuJoCo images, Lucas-Kanade).
    noise_px: standard deviation of the Gaussian pixel noise on each measured position (pixels).
    dropout: probability that a visible flow is dropped. outliers: outlier flows per frame as a fraction
    of the visible count (uniform positions in the image, uniform velocities, see ``OUTLIER_SPEED``).
    camera_prior: what the camera knows of itself and writes into the observation: "none" (the paper's
    setting), "gravity" (its tilt, as from an IMU: the gravity direction in the camera frame) or "floor"
    (gravity and its height above the floor).
    """

    mode: str = "geometric"
    noise_px: float = 1.0
    dropout: float = 0.0
    outliers: float = 0.0
    camera_prior: str = "none"

    def __post_init__(self):
        _require(self.mode in OBSERVATION_MODES, "observation.mode", self.mode,
                 f"must be one of {', '.join(OBSERVATION_MODES)}")
        _require(_finite("observation.noise_px", self.noise_px) >= 0.0, "observation.noise_px", self.noise_px,
                 "must be >= 0 (pixels)")
        _require(0.0 <= _finite("observation.dropout", self.dropout) < 1.0, "observation.dropout",
                 self.dropout, "must be in [0, 1)")
        _require(0.0 <= _finite("observation.outliers", self.outliers) <= 10.0, "observation.outliers",
                 self.outliers, "must be in [0, 10] (outliers per visible flow)")
        _require(self.camera_prior in CAMERA_PRIORS, "observation.camera_prior", self.camera_prior,
                 f"must be one of {', '.join(CAMERA_PRIORS)}")


@dataclass(frozen=True)
class SceneSpec:
    """The whole scene: markers, camera, occluders, observation model."""

    markers: MarkerSpec = field(default_factory=MarkerSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    occluders: OccluderSpec = field(default_factory=OccluderSpec)
    observation: ObservationSpec = field(default_factory=ObservationSpec)

    def __post_init__(self):
        for name, kind in (("markers", MarkerSpec), ("camera", CameraSpec), ("occluders", OccluderSpec),
                           ("observation", ObservationSpec)):
            value = getattr(self, name)
            _require(isinstance(value, kind), name, type(value).__name__, f"must be a {kind.__name__}")
