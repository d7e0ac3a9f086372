"""``Motion``: one demonstration of a motion primitive, as humanoid56 configurations over time.

``qpos`` is ``(T, 57)``: base position (m, world), base quaternion (w, x, y, z, world from base), 50 hinge
angles (rad) in the order of ``docs/humanoid56.md``. Velocities are central differences (one-sided at the
ends); the base's angular velocity is differentiated on the rotation group (``log(q_{t-1}^-1 q_{t+1})``),
which is exact for a constant body-frame rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from harness import geometry
from harness.body.model import NQ
from harness.errors import HarnessError
from harness.io import save_npz_atomic


class MotionError(HarnessError):
    """A motion that is malformed or cannot be read."""


#: A capture that holds a joint within this range (degrees) over a whole demonstration does not measure it:
#: the BVH conversions' hands and wrist twist stay at the retargeting's warm start, no capture drives the neck's
#: and head's twist, and some files hold whole limbs at zero (docs/captures.md). A joint a person moves at all
#: moves more than this; the procedural performer's smooth noise moves every joint.
MEASURED_RANGE_DEG = 0.5


@dataclass(frozen=True)
class MotionVelocities:
    """Velocities of a motion, all ``(T, k)`` per second.

    angles: ``(T, 50)`` rad/s. base_linear_world: ``(T, 3)`` m/s in the world frame.
    base_linear: ``(T, 3)`` m/s and base_angular: ``(T, 3)`` rad/s, both in the base frame.
    """

    angles: np.ndarray
    base_linear_world: np.ndarray
    base_linear: np.ndarray
    base_angular: np.ndarray

    def qvel(self) -> np.ndarray:
        """MuJoCo's ``qvel`` layout ``(T, 56)``: world linear, base-frame angular, angle rates."""
        return np.concatenate([self.base_linear_world, self.base_angular, self.angles], axis=1)


@dataclass(frozen=True)
class Motion:
    """A labelled demonstration: ``qpos (T, 57)`` at ``fps`` frames per second.

    label: the motion primitive ("walk", ...). subject: who performed it. demo: an id unique within
    (source, label, subject): a capture's file stem and frame range (``"09_01:1-120"``). source: where it came
    from: ``"procedural"`` or the capture set's name (``"cmu"``). style: the performance's style where the
    capture set names one (``"tired"``), else empty.
    """

    qpos: np.ndarray
    fps: float
    label: str
    subject: str = "0"
    demo: str = "0"
    source: str = "procedural"
    style: str = ""

    def __post_init__(self):
        qpos = np.array(self.qpos, dtype=float)
        if qpos.ndim != 2 or qpos.shape[1] != NQ:
            raise MotionError(f"motion {self.label!r}: qpos must be (T, {NQ}), got {qpos.shape}")
        if len(qpos) < 2:
            raise MotionError(f"motion {self.label!r}: needs at least 2 frames, got {len(qpos)}")
        if not np.isfinite(qpos).all():
            raise MotionError(f"motion {self.label!r}: qpos has NaN or infinite values")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise MotionError(f"motion {self.label!r}: fps must be positive, got {self.fps}")
        norms = np.linalg.norm(qpos[:, 3:7], axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-6):
            raise MotionError(f"motion {self.label!r}: base quaternions must be unit length")
        qpos.setflags(write=False)
        object.__setattr__(self, "qpos", qpos)
        object.__setattr__(self, "fps", float(self.fps))

    # --- views ----------------------------------------------------------------------------------

    @property
    def n_frames(self) -> int:
        return len(self.qpos)

    @property
    def duration(self) -> float:
        return (self.n_frames - 1) / self.fps

    @property
    def angles(self) -> np.ndarray:
        return self.qpos[:, 7:]

    @property
    def measured_joints(self) -> np.ndarray:
        """``(50,)`` bool: the joints this demonstration measures, i.e. that move by more than
        ``MEASURED_RANGE_DEG`` over it (module constant)."""
        return np.ptp(self.angles, axis=0) > np.deg2rad(MEASURED_RANGE_DEG)

    @property
    def base_pos(self) -> np.ndarray:
        return self.qpos[:, :3]

    @property
    def base_quat(self) -> np.ndarray:
        return self.qpos[:, 3:7]

    @property
    def times(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps

    @cached_property
    def velocities(self) -> MotionVelocities:
        """Finite-difference velocities (computed once, then cached)."""
        return velocities_of(self.qpos, self.fps)

    # --- transformations ------------------------------------------------------------------------

    def replace(self, **changes) -> "Motion":
        fields = dict(qpos=self.qpos, fps=self.fps, label=self.label, subject=self.subject, demo=self.demo,
                      source=self.source, style=self.style)
        fields.update(changes)
        return Motion(**fields)

    def slice(self, start: int, stop: int) -> "Motion":
        if not 0 <= start < stop <= self.n_frames:
            raise MotionError(f"frame range [{start}, {stop}) is outside the motion's {self.n_frames} frames")
        return self.replace(qpos=self.qpos[start:stop])

    def resample(self, fps: float) -> "Motion":
        """The same motion at another frame rate over the same time span (linear in angles and position,
        spherical in the base orientation)."""
        if not (np.isfinite(fps) and fps > 0):
            raise MotionError(f"fps must be positive, got {fps}")
        n = int(np.floor(self.duration * fps + 1e-9)) + 1
        if n < 2:
            raise MotionError(f"motion of {self.duration:.3f} s has fewer than 2 frames at {fps} fps")
        t = np.arange(n) / fps * self.fps                 # fractional source frame index
        i0 = np.minimum(np.floor(t).astype(int), self.n_frames - 2)
        a = (t - i0)[:, None]
        q0, q1 = self.qpos[i0], self.qpos[i0 + 1]
        out = (1.0 - a) * q0 + a * q1
        out[:, 3:7] = geometry.slerp(q0[:, 3:7], q1[:, 3:7], a[:, 0])
        return self.replace(qpos=out, fps=fps)

    # --- files ----------------------------------------------------------------------------------

    def save(self, path: str | Path, dtype: type = np.float64, compressed: bool = False) -> None:
        """Write the motion as ``.npz`` (``dtype``: of ``qpos``; the capture library keeps float32, compressed)."""
        save_npz_atomic(path, {
            "qpos": np.asarray(self.qpos, dtype=dtype), "fps": np.array(self.fps), "label": np.array(self.label),
            "subject": np.array(self.subject), "demo": np.array(self.demo), "source": np.array(self.source),
            "style": np.array(self.style),
        }, compressed=compressed)

    @classmethod
    def load(cls, path: str | Path) -> "Motion":
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                qpos = np.asarray(z["qpos"], dtype=float)
                if np.issubdtype(z["qpos"].dtype, np.floating) and z["qpos"].dtype != np.float64:
                    # stored in single precision: unit base quaternions again to double precision
                    qpos[:, 3:7] /= np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)
                return cls(qpos=qpos, fps=float(z["fps"]), label=str(z["label"]), subject=str(z["subject"]),
                           demo=str(z["demo"]), source=str(z["source"]),
                           style=str(z["style"]) if "style" in z.files else "")
        except FileNotFoundError:
            raise MotionError(f"{path}: no such motion file") from None
        except (KeyError, ValueError, OSError) as exc:
            raise MotionError(f"{path}: not a motion file ({exc})") from None


def velocities_of(qpos: np.ndarray, fps: float, scheme: str = "central") -> MotionVelocities:
    """Finite-difference velocities of configurations ``(T, 57)`` at ``fps``: ``scheme`` as in
    ``geometry.finite_difference`` (``"backward"``: over the interval that ends at each frame, as a flow is)."""
    dt = 1.0 / fps
    quat = qpos[:, 3:7]
    lin_world = geometry.finite_difference(qpos[:, :3], dt, scheme)
    lin_base = geometry.rotate(geometry.conjugate(quat), lin_world)
    return MotionVelocities(geometry.finite_difference(qpos[:, 7:], dt, scheme), lin_world, lin_base,
                            geometry.body_angular_velocity(quat, dt, scheme))
