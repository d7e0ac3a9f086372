"""What a procedural motion primitive is: the ``Take`` it writes into, the ``Plan`` it returns, the registry.

The ten primitives themselves are in ``harness.motion.repertoire``; ``@primitive(name)`` registers one and
``lookup(name)`` finds it (an unknown name raises ``UnknownPrimitiveError`` listing the valid ones). Also
here: ``soft_clip`` (joint limits), ``smooth_noise`` (low-passed variability), ``mirror`` (the other side).

A primitive is a function ``plan(take: Take) -> Plan``: from one take's timing, amplitude and random draws it
writes the 50 hinge angles (degrees, in *anatomical* terms: see ``Take.lr``) and the base's orientation sway
over time, and marks the frames in which the body is airborne. It does not place the base: the performer
(``harness.motion.performer``) puts the feet on the floor and moves the base so that the supporting foot
does not slide, which is what makes walking advance and squatting lower the pelvis.

Conventions (``docs/humanoid56.md``): flexion of hip, shoulder and elbow is negative y; flexion of knee,
ankle (plantar) and forward bending of spine and neck is positive y. ``Take.lr`` takes values for the left
side and mirrors them to the right (x and z negated), so abduction and external rotation are positive for
both sides as written here. The base's orientation sway is described in ``Plan``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from harness.body.model import JOINT_NAMES, N_ANGLES, mirror_angles
from harness.errors import HarnessError

_INDEX = {name: i for i, name in enumerate(JOINT_NAMES)}


class PerformerError(HarnessError):
    """Bad input to the procedural performer (a parameter out of its domain)."""


class UnknownPrimitiveError(PerformerError):
    """A motion class that the performer does not know."""


@dataclass
class Plan:
    """What a primitive produces for one take of ``T`` frames.

    angles: ``(T, 50)`` degrees, model order (right side already mirrored).
    yaw, pitch, roll: ``(T,)`` degrees, the base's orientation ``Rz(yaw) Ry(pitch) Rx(roll)``; pitch > 0
    tips the pelvis forward, roll > 0 lowers its right side, yaw > 0 turns it to the left.
    flight: ``(T,)`` bool, frames in which neither foot touches the floor (ballistic base height).
    flight_speed: forward base speed (m/s, along the heading) added during flight, for jumps that travel.
    """

    angles: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    flight: np.ndarray
    flight_speed: float = 0.0


class Take:
    """One take's timing and draws, and the helpers primitives write joint trajectories with.

    fps: frames per second. tempo: multiplies every duration (> 1 is slower). amp: multiplies movement
    amplitudes. rng: this take's generator (durations, phases). A primitive first draws its timeline and
    calls ``begin(duration)``, which sets ``t`` (``(T,)`` seconds) and zeroes the trajectories.

    The class calibration (``harness.motion.calibration``) enters through ``gain`` ``(50,)``, which
    multiplies every movement a primitive writes into a joint (``add``, ``lr`` and what calls them; not the
    ankle that ``flat_feet`` solves for), ``lean_gain`` (pitch, roll), which multiplies what ``lean`` adds
    to the base's tilt, ``extent``, which multiplies the durations of ``span`` and the number of cycles of
    ``cycles`` (not the period of a cyclic primitive), and the class posture, which is part of ``posture``,
    ``pitch`` and ``roll``.
    """

    def __init__(self, fps: float, tempo: float, amp: float, rng: np.random.Generator,
                 posture: np.ndarray | None = None, pitch: float = 0.0, noise: np.ndarray | None = None,
                 base_noise: np.ndarray | None = None, smoothing_s: float = 0.2,
                 limits: tuple[np.ndarray, np.ndarray] | None = None, gain: np.ndarray | None = None,
                 extent: float = 1.0, roll: float = 0.0, lean_gain: tuple[float, float] = (1.0, 1.0)):
        self.fps, self.tempo, self.amp, self.rng = fps, tempo, amp, rng
        self.limits = limits
        self.gain = np.ones(N_ANGLES) if gain is None else np.asarray(gain, dtype=float)
        self.extent = extent
        self.posture_roll = roll
        self.lean_gain = lean_gain
        self.posture = np.zeros(N_ANGLES) if posture is None else np.asarray(posture, dtype=float)
        self.posture_pitch = pitch
        self.noise = np.zeros(N_ANGLES) if noise is None else np.asarray(noise, dtype=float)
        self.base_noise = np.zeros(3) if base_noise is None else np.asarray(base_noise, dtype=float)
        self.smoothing_s = smoothing_s
        self.t = np.zeros(0)

    def begin(self, duration: float) -> np.ndarray:
        """Allocate ``round(duration * fps) + 1`` frames; returns the times ``(T,)`` in seconds.

        Trajectories start from the subject's posture plus smooth noise (``posture``, ``noise`` per joint
        and ``base_noise`` for yaw, pitch, roll, all degrees), so that what a primitive computes from the
        current angles (``flat_feet``) sees the whole pose.
        """
        n = int(round(duration * self.fps)) + 1
        self.t = np.arange(n) / self.fps
        self.angles = self.posture + smooth_noise(self.rng, n, self.noise, self.fps, self.smoothing_s)
        ypr = smooth_noise(self.rng, n, self.base_noise, self.fps, self.smoothing_s)
        self.yaw, self.pitch, self.roll = ypr[:, 0], ypr[:, 1] + self.posture_pitch, ypr[:, 2] + self.posture_roll
        self.flight = np.zeros(n, dtype=bool)
        return self.t

    def add(self, joint: str, deg) -> None:
        """Add degrees to one joint (model sign convention), times its gain."""
        i = _INDEX[joint]
        self.angles[:, i] += self.gain[i] * np.asarray(deg)

    def lean(self, pitch=0.0, roll=0.0) -> None:
        """Add degrees to the base's pitch (> 0 tips the pelvis forward) and roll (> 0 lowers its right
        side), times their gains (``lean_gain``)."""
        self.pitch = self.pitch + self.lean_gain[0] * np.asarray(pitch)
        self.roll = self.roll + self.lean_gain[1] * np.asarray(roll)

    def lr(self, joint: str, left=0.0, right=0.0) -> None:
        """Add anatomical degrees to a joint of both sides (``joint`` without the l/r prefix).

        The right side mirrors the left: its x (ab/adduction) and z (twist) angles are negated, so the same
        value means the same anatomical movement on both sides.
        """
        sign = -1.0 if joint.endswith(("_x", "_z")) else 1.0
        self.add("l" + joint, left)
        self.add("r" + joint, sign * np.asarray(right))

    def both(self, joint: str, deg) -> None:
        self.lr(joint, deg, deg)

    def spine(self, axis: str, deg) -> None:
        """Spread a trunk angle over lower back, upper back and thorax (40/30/30 %)."""
        for part, share in (("lowerback", 0.4), ("upperback", 0.3), ("thorax", 0.3)):
            self.add(f"{part}_{axis}", share * np.asarray(deg))

    def neck(self, axis: str, deg) -> None:
        """Spread a neck angle over lower neck, upper neck and head (40/30/30 %)."""
        for part, share in (("lowerneck", 0.4), ("upperneck", 0.3), ("head", 0.3)):
            self.add(f"{part}_{axis}", share * np.asarray(deg))

    def flat_feet(self, weight_left, weight_right=None) -> None:
        """Set the ankles so that the soles stay parallel to the floor (sagittal plane), by ``weight``.

        The sole's pitch is base pitch + hip + knee + ankle (all about parallel y axes), so the ankle that
        keeps it flat is minus the sum of the others.
        """
        weight_right = weight_left if weight_right is None else weight_right
        # Hip and knee as they will be after soft clipping (the ankle is clipped in its turn afterwards).
        legs = self.angles if self.limits is None else soft_clip(self.angles, *self.limits)
        for side, w in (("l", weight_left), ("r", weight_right)):
            chain = (self.pitch + legs[:, _INDEX[side + "femur_y"]]
                     + legs[:, _INDEX[side + "tibia_y"]] + self.angles[:, _INDEX[side + "foot_y"]])
            self.angles[:, _INDEX[side + "foot_y"]] -= np.asarray(w) * chain

    def plan(self, flight_speed: float = 0.0) -> Plan:
        return Plan(self.angles, self.yaw, self.pitch, self.roll, self.flight, flight_speed)

    # --- time shapes ---------------------------------------------------------------------------

    def span(self, lo: float, hi: float) -> float:
        """A duration drawn uniformly from ``[lo, hi]`` seconds, times the tempo and the extent."""
        return float(self.rng.uniform(lo, hi)) * self.tempo * self.extent

    def scaled(self, seconds: float) -> float:
        """A fixed duration (seconds) times the tempo and the extent, like ``span``'s."""
        return seconds * self.tempo * self.extent

    def period(self, lo: float, hi: float) -> float:
        """A cycle period drawn uniformly from ``[lo, hi]`` seconds, times the tempo."""
        return float(self.rng.uniform(lo, hi)) * self.tempo

    def cycles(self, lo: float, hi: float) -> float:
        """A number of cycles drawn uniformly from ``[lo, hi]``, times the extent."""
        return float(self.rng.uniform(lo, hi)) * self.extent

    def keys(self, *knots: tuple[float, float]) -> np.ndarray:
        """A profile through ``(time s, value)`` knots, minimum-jerk between them, held outside."""
        times = np.array([k[0] for k in knots])
        values = np.array([k[1] for k in knots], dtype=float)
        i = np.clip(np.searchsorted(times, self.t, side="right") - 1, 0, len(times) - 2)
        dt = np.maximum(times[i + 1] - times[i], 1e-9)
        s = np.clip((self.t - times[i]) / dt, 0.0, 1.0)
        s = s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
        return values[i] + (values[i + 1] - values[i]) * s


CLIP_MARGIN = 0.08              # fraction of each joint range used by the soft clip


def soft_clip(angles: np.ndarray, lower: np.ndarray, upper: np.ndarray, margin: float = CLIP_MARGIN
              ) -> np.ndarray:
    """Clip ``angles (..., J)`` into ``[lower, upper] (J,)`` softly (any unit): identity in the interior, and
    in the outer ``margin`` fraction of the range ``edge + m tanh((x - edge) / m)``, which is C1 and reaches
    the limit only asymptotically."""
    m = margin * (upper - lower)
    hi, lo = upper - m, lower + m
    out = np.where(angles > hi, hi + m * np.tanh((angles - hi) / m), angles)
    return np.where(out < lo, lo + m * np.tanh((out - lo) / m), out)


def mirror(plan: Plan) -> Plan:
    """The same movement performed with the other side (a left-handed or left-footed performer)."""
    return Plan(mirror_angles(plan.angles), -plan.yaw, plan.pitch.copy(), -plan.roll, plan.flight.copy(),
                plan.flight_speed)


def smooth_noise(rng: np.random.Generator, n: int, scale: np.ndarray, fps: float, smoothing_s: float
                 ) -> np.ndarray:
    """Low-pass Gaussian noise ``(n, len(scale))`` whose per-column standard deviation is ``scale``.

    White noise filtered by a unit-sum Gaussian of ``s = smoothing_s * fps`` samples has standard deviation
    ``(2 sqrt(pi) s)^-1/2``; multiplying by its inverse restores unit variance.
    """
    scale = np.asarray(scale, dtype=float)
    s = smoothing_s * fps
    white = rng.standard_normal((n, len(scale)))
    smooth = gaussian_filter1d(white, s, axis=0, mode="reflect") * np.sqrt(2.0 * np.sqrt(np.pi) * s)
    return smooth * scale


def bump(phase: np.ndarray, centre: float, sharpness: float) -> np.ndarray:
    """A smooth periodic bump in ``[0, 1]``, 1 at ``centre`` (radians), narrower for larger sharpness."""
    return (0.5 * (1.0 + np.cos(phase - centre))) ** sharpness


def window(t: np.ndarray, start: float, stop: float) -> np.ndarray:
    return (t >= start) & (t < stop)


# --- registry ------------------------------------------------------------------------------------

PrimitiveFn = Callable[[Take], Plan]
_REGISTRY: dict[str, PrimitiveFn] = {}
_CYCLIC: set[str] = set()


def primitive(name: str, cyclic: bool = False):
    """Register ``plan(take) -> Plan`` as the motion class ``name``; ``cyclic``: a periodic primitive (a gait,
    a wave), whose HMM may wrap from its last state to its first."""
    def register(fn: PrimitiveFn) -> PrimitiveFn:
        if name in _REGISTRY:
            raise ValueError(f"motion primitive {name!r} is registered twice")
        _REGISTRY[name] = fn
        if cyclic:
            _CYCLIC.add(name)
        return fn
    return register


def cyclic_primitives() -> tuple[str, ...]:
    """Names of the registered periodic primitives, in registration order."""
    return tuple(n for n in _REGISTRY if n in _CYCLIC)


def registered() -> tuple[str, ...]:
    """Names of the registered primitives, in registration order."""
    return tuple(_REGISTRY)


def lookup(name: str) -> PrimitiveFn:
    """The primitive registered as ``name``; an unknown name raises ``UnknownPrimitiveError``."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise UnknownPrimitiveError(
            f"unknown motion class {name!r}; valid classes: {', '.join(_REGISTRY)}") from None
