"""The procedural performer: labelled demonstrations of ten whole-body motion primitives.

``demonstrations(label, n, rng)`` plays a primitive (``harness.motion.repertoire``) ``n`` times with
demonstration-to-demonstration variability, and returns humanoid56 ``Motion``s:

- **subject style** (``subject_style``): a fixed tempo and amplitude bias and posture offsets per subject id
  (trunk lean, arm carriage, stance width, toe-out, head tilt), drawn from the subject id alone;
- **per take**: tempo and amplitude factors (together about +-15 %), random phase, random rest lengths,
  and smooth noise on every angle and on the base orientation (white noise low-passed by a Gaussian of
  ``NOISE_SMOOTHING_S`` seconds);
- **left-sided performances**: a subject whose laterality is below the primitive's left share performs the
  mirror image (left kick, left punch...);
- **class calibration** (``harness.motion.calibration``): per primitive, a posture, movement gains, an extent
  (timing) and a left share fitted on real captures;
- angles are soft-clipped into the joint ranges (identity inside, tanh saturation in the outer
  ``primitives.CLIP_MARGIN`` of each range), so no angle ever leaves its range.

The base is placed from the feet (``place_base``): its height puts the lowest foot or toe point exactly on
the floor (z = 0) in every frame that is not airborne, and follows a ballistic arc in airborne frames; its
horizontal position moves so that the supporting foot (the lower one, blended over 1 cm) does not slide.
So walking advances, a squat lowers the pelvis and a jump leaves the ground because of what the legs do.
Every demonstration starts at x = y = 0 with heading 0 (facing +x).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from harness import geometry
from harness.body import BodyModel, forward_points, geom_z_range, nominal_body
from harness.body.model import JOINT_NAMES
from harness.motion import repertoire  # noqa: F401  (registers the primitives)
from harness.motion.calibration import NEUTRAL, ClassCalibration, default_calibration
from harness.motion.motion import Motion
from harness.motion.primitives import (PerformerError, Plan, Take, cyclic_primitives, lookup, mirror, registered,
                                       soft_clip)
from harness.randomness import named_generator

CLASSES: tuple[str, ...] = ("walk", "run", "jump", "squat", "kick", "punch", "wave", "bow", "throw",
                            "jumping_jack")
# The periodic primitives (registered with ``cyclic=True``): every tool that learns a database passes them as its
# HMMs' wrapping classes; capture sets use the same class names.
CYCLIC: tuple[str, ...] = cyclic_primitives()
STANDING_HEIGHT = 0.95          # m, pelvis height of the zero pose with the soles on the floor
GRAVITY = 9.81                  # m/s^2, for the airborne arcs
CONTACT_BLEND = 0.01            # m, height difference over which support passes from one foot to the other
NOISE_SMOOTHING_S = 0.18        # s, standard deviation of the Gaussian that low-passes the angle noise
TEMPO_SPREAD = 0.10             # per take, uniform +-, multiplies durations
AMP_SPREAD = 0.10               # per take, uniform +-, multiplies amplitudes
SUBJECT_SPREAD = 0.05           # per subject, log-normal sigma of the tempo and amplitude biases
NOISE_GAIN = 2.0                # multiplies the per-joint smooth-noise levels of _NOISE_DEG
POSTURE_GAIN = 2.0              # multiplies the subject posture offsets
CARRIAGE_RANGE = (0.25, 1.75)   # per subject, uniform factor on a primitive's calibrated class posture
_STYLE_SEED = 0x5EB1EC7         # fixed: a subject id always gives the same style
_FOOT_GEOMS = ("lfoot", "ltoes", "rfoot", "rtoes")

# Smooth-noise standard deviation per joint (degrees): more in the arms and hands, which people carry
# freely, less in the legs, whose errors would show as sliding or uneven feet.
_NOISE_DEG = {"lowerback": 2.0, "upperback": 1.5, "thorax": 1.5, "lowerneck": 3.0, "upperneck": 3.0,
              "head": 3.0, "clavicle": 2.0, "humerus": 4.5, "radius": 6.0, "wrist": 6.0, "hand": 5.0,
              "femur": 1.2, "tibia": 1.5, "foot": 2.0, "toes": 3.0}
_BASE_NOISE_DEG = np.array([2.0, 1.0, 1.0])        # yaw, pitch, roll


def _noise_scale() -> np.ndarray:
    out = np.empty(len(JOINT_NAMES))
    for i, name in enumerate(JOINT_NAMES):
        part = name.split("_")[0]
        part = part[1:] if part[0] in "lr" and part[1:] in _NOISE_DEG else part
        out[i] = _NOISE_DEG[part]
    return out


_NOISE_SCALE_DEG = NOISE_GAIN * _noise_scale()


@dataclass(frozen=True)
class SubjectStyle:
    """A performer's fixed manner: tempo and amplitude biases and posture offsets.

    tempo, amplitude: multiplicative biases (about 1). posture: ``(50,)`` degrees added to every frame
    (model sign convention). pitch: degrees of extra forward pelvis tilt. laterality: uniform in [0, 1);
    the subject performs a primitive with the left side, as a mirror image, when it is below the
    primitive's left share (``calibration.ClassCalibration.left``; ``calibration.DEFAULT_LEFT`` by default).
    carriage: how strongly the subject adopts a primitive's calibrated class posture of the joints (a factor;
    the class's base lean is taken as calibrated).
    """

    subject: int
    tempo: float
    amplitude: float
    posture: np.ndarray
    pitch: float
    laterality: float = 1.0
    carriage: float = 1.0


def subject_style(subject: int) -> SubjectStyle:
    """The style of subject ``subject`` (a non-negative int); the same id always gives the same style."""
    if isinstance(subject, bool) or not isinstance(subject, (int, np.integer)) or subject < 0:
        raise PerformerError(f"subject must be a non-negative integer, got {subject!r}")
    g = np.random.default_rng([_STYLE_SEED, int(subject)])
    tempo = float(np.exp(g.normal(0.0, SUBJECT_SPREAD)))
    amplitude = float(np.exp(g.normal(0.0, SUBJECT_SPREAD)))
    k = Take(30.0, 1.0, 1.0, g)                           # one frame, used only for its anatomical helpers
    k.begin(0.0)
    k.spine("y", g.normal(0.0, 3.0))                     # slouch or upright
    k.spine("x", g.normal(0.0, 1.5))
    k.neck("y", g.normal(0.0, 5.0))
    k.neck("x", g.normal(0.0, 2.0))
    k.both("clavicle_x", g.normal(0.0, 3.0))              # shoulders raised or dropped
    k.both("humerus_x", abs(g.normal(0.0, 4.0)))          # arms held off the body
    k.both("humerus_z", g.normal(0.0, 6.0))
    k.both("radius_y", -abs(g.normal(0.0, 6.0)))         # elbows a little bent
    k.both("femur_x", g.normal(1.0, 2.0))                 # stance width
    k.both("femur_z", g.normal(4.0, 4.0))                 # toe-out
    pitch, laterality = float(g.normal(0.0, 2.0)), float(g.uniform())
    return SubjectStyle(int(subject), tempo, amplitude, POSTURE_GAIN * k.angles[0].copy(), pitch, laterality,
                        float(g.uniform(*CARRIAGE_RANGE)))


def _orientation(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Quaternions ``(T, 4)`` of ``Rz(yaw) Ry(pitch) Rx(roll)`` from radians."""
    zero = np.zeros_like(yaw)
    qz = geometry.exp(np.stack([zero, zero, yaw], axis=1))
    qy = geometry.exp(np.stack([zero, pitch, zero], axis=1))
    qx = geometry.exp(np.stack([roll, zero, zero], axis=1))
    return geometry.multiply(qz, geometry.multiply(qy, qx))


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` frame ranges of the True runs of a boolean mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def place_base(body: BodyModel, angles: np.ndarray, quat: np.ndarray, flight: np.ndarray, fps: float,
               flight_speed: float = 0.0) -> np.ndarray:
    """Base positions ``(T, 3)`` (m) for angles ``(T, 50)`` rad and base orientations ``(T, 4)``.

    Grounded frames (``flight`` False): the lowest point of the foot and toe geoms is at z = 0, and the base
    moves horizontally by minus the displacement of the supporting foot (relative to the base), support
    being blended between the feet by ``sigmoid((z_right - z_left) / CONTACT_BLEND)``. Airborne frames: the
    base keeps the horizontal velocity of the surrounding support (plus ``flight_speed`` m/s along the
    heading) and its height follows a ballistic arc from take-off to landing (never below the grounded
    height, so no foot goes through the floor). Starts at x = y = 0.
    """
    n = len(angles)
    flight = np.asarray(flight, dtype=bool)
    m = body.model
    geoms = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in _FOOT_GEOMS])
    q = body.qpos(angles, base_pos=np.array([0.0, 0.0, STANDING_HEIGHT]), base_quat=quat)
    low = geom_z_range(body, q, geoms)[:, :, 0]                       # (T, 4) lowest z per geom
    z_left, z_right = low[:, :2].min(axis=1), low[:, 2:].min(axis=1)
    soles = forward_points(body, q, m.geom_bodyid[geoms[[0, 2]]], m.geom_pos[geoms[[0, 2]]])[:, :, :2]
    w = 1.0 / (1.0 + np.exp(-np.clip((z_right - z_left) / CONTACT_BLEND, -50, 50)))   # weight of the left
    wm = 0.5 * (w[1:] + w[:-1])[:, None]
    d = np.diff(soles, axis=0)                                        # (T-1, 2 feet, 2)
    step = -(wm * d[:, 0] + (1.0 - wm) * d[:, 1])                     # (T-1, 2)
    z = STANDING_HEIGHT - np.minimum(z_left, z_right)

    airborne_step = flight[1:] | flight[:-1]
    segments = _segments(flight)
    full = [b - a for a, b in segments if a > 0 and b < n]
    full_len = max(full) if full else max((b - a for a, b in segments), default=0)
    window = max(1, int(round(0.2 * fps)))
    heading = geometry.heading(quat)
    dt = 1.0 / fps
    z_out = z.copy()
    for a, b in segments:
        # Horizontal: the mean grounded velocity around the flight, plus the primitive's own travel.
        lo, hi = max(0, a - 1 - window), min(n - 1, b + window)
        grounded = ~airborne_step[lo:hi]
        v = step[lo:hi][grounded].mean(axis=0) if grounded.any() else np.zeros(2)
        h = heading[a:b].mean()
        v = v + flight_speed * dt * np.array([np.cos(h), np.sin(h)])
        s_lo, s_hi = max(0, a - 1), min(n - 1, b)
        step[s_lo:s_hi] = v
        # Vertical: ballistic arc z0 + (z1 - z0) s + g T^2 s (1 - s) / 2 over the flight of T seconds.
        if a > 0 and b < n:
            start, length, z0, z1 = a - 1, b - a + 1, z[a - 1], z[b]
        elif a == 0:
            length = full_len + 1
            start, z0 = b - length, z[min(b, n - 1)]
            z1 = z0
        else:
            start, length, z0 = a - 1, full_len + 1, z[a - 1]
            z1 = z0
        frames = np.arange(a, b)
        s = (frames - start) / length
        dur = length * dt
        arc = z0 + (z1 - z0) * s + 0.5 * GRAVITY * dur**2 * s * (1.0 - s)
        z_out[a:b] = np.maximum(arc, z[a:b])
    xy = np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])
    return np.column_stack([xy, z_out])


def perform(label: str, rng: np.random.Generator, fps: float = 30.0, subject: int | None = None,
            body: BodyModel | None = None, demo: str = "0", calibration: ClassCalibration | None = None,
            left: float | None = None) -> tuple[Motion, np.ndarray]:
    """One demonstration of ``label`` (see ``demonstrations``) and its airborne frames ``(T,)`` bool.

    The airborne mask says which frames the primitive planned off the ground (both feet in the air); in all
    other frames the lowest foot point is on the floor. Useful as contact labels and for checks.
    ``calibration``: the class's calibration (default: the shipped table's, ``calibration.NEUTRAL`` for a
    class it lacks); ``NEUTRAL`` plays the primitive as written. ``left``: the left share in [0, 1] to use
    instead of the calibration's (1: left-sided whatever the subject, 0: right-sided).
    """
    fn = lookup(label)
    if not (np.isfinite(fps) and fps > 0):
        raise PerformerError(f"fps must be positive, got {fps}")
    body = nominal_body() if body is None else body
    cal = default_calibration().get(label, NEUTRAL) if calibration is None else calibration
    if left is not None and not 0.0 <= left <= 1.0:
        raise PerformerError(f"left share must be in [0, 1], got {left}")
    left = cal.left if left is None else left
    if subject is None:
        subject = int(rng.integers(0, 1000))
    style = subject_style(subject)
    tempo = style.tempo * rng.uniform(1.0 - TEMPO_SPREAD, 1.0 + TEMPO_SPREAD)
    amp = style.amplitude * rng.uniform(1.0 - AMP_SPREAD, 1.0 + AMP_SPREAD)
    take = Take(fps, tempo, amp, rng, posture=style.posture + style.carriage * cal.posture,
                pitch=style.pitch + cal.lean[0],
                noise=_NOISE_SCALE_DEG, base_noise=_BASE_NOISE_DEG, smoothing_s=NOISE_SMOOTHING_S,
                limits=(np.rad2deg(body.lower), np.rad2deg(body.upper)), gain=cal.gain, extent=cal.extent,
                roll=cal.lean[1], lean_gain=tuple(cal.lean_gain))
    plan: Plan = fn(take)
    if style.laterality < left:
        plan = mirror(plan)
    angles = soft_clip(np.deg2rad(plan.angles), body.lower, body.upper)
    ypr = np.deg2rad(np.column_stack([plan.yaw, plan.pitch, plan.roll]))
    ypr[:, 0] -= ypr[0, 0]                                            # heading 0 at the first frame
    quat = _orientation(ypr[:, 0], ypr[:, 1], ypr[:, 2])
    base = place_base(body, angles, quat, plan.flight, fps, plan.flight_speed)
    qpos = body.qpos(angles, base_pos=base, base_quat=quat)
    motion = Motion(qpos=qpos, fps=fps, label=label, subject=str(subject), demo=demo, source="procedural")
    return motion, plan.flight.copy()


#: Farthest (m) a take's base may get from its start, horizontally: walks and runs stay in a camera's view.
TRAVEL_LIMIT = 3.3
WALK_SPEED_LIMIT = 1.9            # m/s, a brisk walk
FLOOR_TOLERANCE = 0.01            # m, how far below the floor a body part other than the feet may dip


def guarantee_violations(motion: Motion, body: BodyModel | None = None, margin: float = 0.0,
                         clearance: float = 0.0) -> list[str]:
    """What a take breaks of the performer's guarantees beyond joint limits and grounded feet (which hold by
    construction): no body part more than ``FLOOR_TOLERANCE`` below the floor, the base within
    ``TRAVEL_LIMIT`` of its start, a walk no faster than ``WALK_SPEED_LIMIT``. ``margin`` tightens the
    travel and speed bounds by that fraction, ``clearance`` (m) the floor bound of every part but the feet.
    Empty when all hold; the calibration fit (``harness.motion.realism``) keeps its tables within them."""
    body = nominal_body() if body is None else body
    out = []
    lows = geom_z_range(body, motion.qpos)[:, :, 0].min(axis=0)
    feet = np.isin(body.body_geoms, [mujoco.mj_name2id(body.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in _FOOT_GEOMS])
    low = float(lows.min())
    if low < -FLOOR_TOLERANCE or lows[~feet].min() < -FLOOR_TOLERANCE + clearance:
        out.append(f"a body part {-100 * min(low, lows[~feet].min()):.1f} cm below the floor")
    travel = float(np.linalg.norm(motion.base_pos[:, :2] - motion.base_pos[0, :2], axis=1).max())
    if travel > TRAVEL_LIMIT * (1.0 - margin):
        out.append(f"travels {travel:.2f} m")
    if motion.label == "walk" and (speed := travel / motion.duration) > WALK_SPEED_LIMIT * (1.0 - margin):
        out.append(f"walks at {speed:.2f} m/s")
    return out


def demonstrations(label: str, n: int, rng: np.random.Generator, fps: float = 30.0,
                   subject: int | None = None, body: BodyModel | None = None,
                   calibration: ClassCalibration | None = None, left: float | None = None) -> list[Motion]:
    """``n`` demonstrations of the primitive ``label`` (one of ``CLASSES``), as ``Motion``s at ``fps``.

    Each is drawn from ``rng`` in turn (same generator state, bit-identical output). ``subject`` fixes the
    performer's style; ``None`` draws a subject id in [0, 1000) per demonstration. Demo ids are "0".."n-1".
    ``calibration``, ``left``: see ``perform``.
    """
    lookup(label)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise PerformerError(f"number of demonstrations must be a non-negative integer, got {n!r}")
    return [perform(label, rng, fps, subject, body, demo=str(i), calibration=calibration, left=left)[0]
            for i in range(n)]


if set(CLASSES) != set(registered()):      # a primitive added to the repertoire must be named here too
    raise ImportError(f"CLASSES {CLASSES} and the registered primitives {registered()} disagree")


def training_set(classes: tuple[str, ...] | list[str], demos: int, seed: int, fps: float = 30.0,
                 body: BodyModel | None = None) -> list[Motion]:
    """The procedural training set of a database: ``demos`` demonstrations of each class, by subjects
    ``0 .. demos-1``, class ``c`` drawn from ``named_generator(seed, "train/<c>")`` (so a class's demonstrations
    do not depend on which other classes are listed). The one recipe ``harness train-database`` and the
    evaluation share: "a database trained with seed 0" means the same thing in both."""
    out: list[Motion] = []
    for c in classes:
        rng = named_generator(seed, f"train/{c}")
        out += [demonstrations(c, 1, rng, fps=fps, subject=s, body=body)[0] for s in range(demos)]
    return out

