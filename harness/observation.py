"""What the camera gives the engine: per frame, an unordered set of 2D flows, and the camera intrinsics.

This is the wall between the harness and the engine: the engine reads nothing else about the scene.

Frame ``t`` holds ``M_t`` flows, rows ``(u, v, du, dv)``: the feature's pixel position in frame ``t`` and its
image velocity ``(p_t - p_{t-1}) * fps`` in pixels per second. Frame 0 has no predecessor and is empty.
Rows carry no identity and come in no particular order. An empty frame (everything occluded) is legal.

File format (``.npz``, no pickled objects), so that flows from real video can be fed to the engine:

| key | shape | meaning |
|---|---|---|
| ``flows`` | ``(N, 4)`` float | all flows of all frames, rows ``(u, v, du, dv)`` |
| ``frame`` | ``(N,)`` int | the frame each row belongs to, non-decreasing |
| ``n_frames`` | ``()`` int | number of frames ``T`` (frames may be empty) |
| ``fps`` | ``()`` float | frame rate |
| ``intrinsics`` | ``(6,)`` float | ``[width, height, fx, fy, cx, cy]`` (see ``harness.pinhole``) |
| ``camera_motion`` | ``(T, 6)`` float, optional | camera linear (m/s) and angular (rad/s) velocity in its own frame |
| ``gravity`` | ``(T, 3)`` float, optional | unit vector of gravity (down) in the camera frame, e.g. from an IMU |
| ``camera_height`` | ``(T,)`` float, optional | the camera centre's height above the floor, metres (>= 0) |

The last two are the camera prior: a robot's camera usually knows its own tilt, and often its height. The
engine uses them when present and works without them.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.errors import EngineError, HarnessError
from harness.io import inspect_npz, save_npz_atomic
from harness.pinhole import Intrinsics


def _why(exc: Exception) -> str:
    """A file-format failure in words, without quoting the file's content."""
    if isinstance(exc, EOFError) or (isinstance(exc, OSError) and not isinstance(exc, zipfile.BadZipFile)):
        return "empty or truncated"
    if isinstance(exc, zipfile.BadZipFile):
        return "not an .npz archive or truncated"
    return f"malformed arrays: {type(exc).__name__}"


MAX_FRAMES = 1_000_000      # a larger frame count is a corrupt file, not a recording (9 hours at 30 fps)
MAX_FILE_BYTES = 512 * 2**20   # an observation file, and what its arrays expand to
MAX_FPS = 10_000.0
MAX_FLOW_SPEED = 1e7        # px/s: an image side (8192 px) per frame at 1000 fps is 8e6
MAX_CAMERA_SPEED = 1e4      # m/s and rad/s of camera_motion
MAX_CAMERA_HEIGHT = 1e4     # m
# The arrays a file must or may hold, and the kinds of number each may be (numpy dtype kinds: signed and
# unsigned integers, floats). Bool, complex, strings and objects are refused before anything is cast.
_KINDS = {"flows": "iuf", "frame": "iuf", "n_frames": "iuf", "fps": "iuf", "intrinsics": "iuf",
          "camera_motion": "iuf", "gravity": "iuf", "camera_height": "iuf"}


class ObservationError(EngineError):
    """Observations that the engine cannot use (NaN, outside the image, a malformed camera prior or file)."""


@dataclass
class Observation:
    """A sequence of unlabeled flow sets seen by one camera.

    fps: frames per second. intrinsics: the camera's pinhole intrinsics.
    flows: list of ``T`` arrays ``(M_t, 4)``: ``u, v`` (pixels), ``du, dv`` (pixels/s).
    camera_motion: ``(T, 6)`` camera velocity (linear m/s, angular rad/s, camera frame) or None (static).
    gravity: ``(T, 3)`` unit gravity direction in the camera frame, or None (unknown tilt).
    camera_height: ``(T,)`` camera height above the floor (m), or None (unknown).
    """

    fps: float
    intrinsics: Intrinsics
    flows: list[np.ndarray]
    camera_motion: np.ndarray | None = None
    gravity: np.ndarray | None = None
    camera_height: np.ndarray | None = None

    def __post_init__(self):
        self.flows = [np.asarray(f, dtype=float).reshape(-1, 4) for f in self.flows]
        for name in ("camera_motion", "gravity", "camera_height"):
            if getattr(self, name) is not None:
                setattr(self, name, np.asarray(getattr(self, name), dtype=float))

    def __len__(self) -> int:
        return len(self.flows)

    @property
    def counts(self) -> np.ndarray:
        return np.array([len(f) for f in self.flows], dtype=int)

    def validate(self) -> "Observation":
        """Raise ``ObservationError`` naming the frame, row and problem; return self when usable."""
        if not (np.isfinite(self.fps) and 0 < self.fps <= MAX_FPS):
            raise ObservationError(f"fps must be a positive number up to {MAX_FPS:g}, got {self.fps}")
        w, h = self.intrinsics.width, self.intrinsics.height
        for t, f in enumerate(self.flows):
            if len(f) == 0:
                continue
            bad = ~np.isfinite(f).all(axis=1)
            if bad.any():
                raise ObservationError(f"frame {t}, row {int(np.argmax(bad))}: flow has NaN or infinite values")
            outside = (f[:, 0] < 0) | (f[:, 1] < 0) | (f[:, 0] >= w) | (f[:, 1] >= h)
            if outside.any():
                r = int(np.argmax(outside))
                raise ObservationError(f"frame {t}, row {r}: position ({f[r, 0]:.1f}, {f[r, 1]:.1f}) px is "
                                       f"outside the {w}x{h} image")
            fast = np.abs(f[:, 2:]).max(axis=1) > MAX_FLOW_SPEED
            if fast.any():
                raise ObservationError(f"frame {t}, row {int(np.argmax(fast))}: image velocity beyond "
                                       f"{MAX_FLOW_SPEED:g} px/s")
        if self.camera_motion is not None:
            if self.camera_motion.shape != (len(self.flows), 6):
                raise ObservationError(f"camera_motion must have shape ({len(self.flows)}, 6), "
                                       f"got {self.camera_motion.shape}")
            if not np.isfinite(self.camera_motion).all():
                raise ObservationError("camera_motion has NaN or infinite values")
            if np.abs(self.camera_motion).max(initial=0.0) > MAX_CAMERA_SPEED:
                raise ObservationError(f"camera_motion beyond {MAX_CAMERA_SPEED:g} m/s or rad/s")
        self._validate_prior()
        return self

    def _validate_prior(self) -> None:
        T = len(self.flows)
        if self.gravity is not None:
            g = self.gravity
            if g.shape != (T, 3):
                raise ObservationError(f"gravity must have shape ({T}, 3), got {g.shape}")
            if not np.isfinite(g).all():
                raise ObservationError(f"gravity, frame {int(np.argmax(~np.isfinite(g).all(axis=1)))}: NaN or "
                                       f"infinite values")
            off = np.abs(np.linalg.norm(g, axis=1) - 1.0)
            if off.max() > 1e-3:
                t = int(np.argmax(off))
                raise ObservationError(f"gravity, frame {t}: not a unit vector (norm {np.linalg.norm(g[t]):.4g})")
        if self.camera_height is not None:
            h = self.camera_height
            if h.shape != (T,):
                raise ObservationError(f"camera_height must have shape ({T},), got {h.shape}")
            bad = ~np.isfinite(h) | (h < 0) | (h > MAX_CAMERA_HEIGHT)
            if bad.any():
                t = int(np.argmax(bad))
                raise ObservationError(f"camera_height, frame {t}: must be a finite height in "
                                       f"[0, {MAX_CAMERA_HEIGHT:g}] m, got {h[t]}")
            if self.gravity is None:
                raise ObservationError("camera_height needs gravity: a height above the floor means nothing "
                                       "without knowing which way is down")

    def save(self, path: str | Path) -> None:
        """Write the documented ``.npz`` format atomically."""
        arrays = {
            "flows": np.concatenate(self.flows) if self.flows else np.empty((0, 4)),
            "frame": np.repeat(np.arange(len(self.flows)), self.counts),
            "n_frames": np.array(len(self.flows)),
            "fps": np.array(float(self.fps)),
            "intrinsics": self.intrinsics.as_array(),
        }
        for name in ("camera_motion", "gravity", "camera_height"):
            if getattr(self, name) is not None:
                arrays[name] = getattr(self, name)
        save_npz_atomic(path, arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Observation":
        """Read the documented ``.npz`` format. The file's kind and size, and every array's header (shape,
        kind of number, that its bytes can hold it), are checked before any array is read; frame indices and
        ``n_frames`` must be whole numbers."""
        path = Path(path)
        arrays = inspect_npz(path, ObservationError, "observation", MAX_FILE_BYTES)
        for name in ("flows", "frame", "n_frames", "fps", "intrinsics"):
            if name not in arrays:
                raise ObservationError(f"{path}: not an observation file (no array {name!r})")
        for name, (shape, dtype) in arrays.items():
            if name in _KINDS and dtype.kind not in _KINDS[name]:
                raise ObservationError(f"{path}: {name!r} must hold real numbers, got dtype {dtype}")
        for name in ("n_frames", "fps"):
            if arrays[name][0] not in ((), (1,)):
                raise ObservationError(f"{path}: {name!r} must be one number, got shape {arrays[name][0]}")
        try:
            with np.load(path, allow_pickle=False) as z:
                flows, frame_raw = np.asarray(z["flows"], float), np.asarray(z["frame"])
                n_raw, fps = float(np.asarray(z["n_frames"]).ravel()[0]), float(np.asarray(z["fps"]).ravel()[0])
                intr = Intrinsics.from_array(z["intrinsics"])
                optional = {name: np.asarray(z[name], float) if name in z.files else None
                            for name in ("camera_motion", "gravity", "camera_height")}
        except FileNotFoundError:
            raise ObservationError(f"{path}: no such observation file") from None
        except KeyError as exc:
            raise ObservationError(f"{path}: not an observation file (no array {exc.args[0]!r})") from None
        except (ValueError, TypeError, IndexError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # Empty, truncated or foreign files: name the kind of failure, never the file's bytes.
            raise ObservationError(f"{path}: not an observation file ({_why(exc)})") from None
        except HarnessError as exc:        # intrinsics that describe no camera
            raise ObservationError(f"{path}: {exc}") from None
        if not (np.isfinite(n_raw) and n_raw == round(n_raw) and 0 <= n_raw <= MAX_FRAMES):
            raise ObservationError(f"{path}: 'n_frames' must be a whole number in [0, {MAX_FRAMES}], got {n_raw:g}")
        n_frames = int(n_raw)
        if frame_raw.ndim != 1 or not np.all(np.isfinite(frame_raw)) or np.any(frame_raw != np.round(frame_raw)):
            raise ObservationError(f"{path}: 'frame' must hold one whole frame index per row")
        if len(frame_raw) and np.abs(frame_raw).max() > MAX_FRAMES:
            raise ObservationError(f"{path}: 'frame' indices must be non-decreasing and in [0, n_frames)")
        frame = frame_raw.astype(np.int64)
        if flows.ndim != 2 or flows.shape[1] != 4 or frame.ndim != 1 or len(frame) != len(flows):
            raise ObservationError(f"{path}: 'flows' must be (N, 4) with one 'frame' index per row")
        if len(frame) and (frame.min() < 0 or frame.max() >= n_frames or np.any(np.diff(frame) < 0)):
            raise ObservationError(f"{path}: 'frame' indices must be non-decreasing and in [0, n_frames)")
        bounds = np.searchsorted(frame, np.arange(n_frames + 1))
        try:
            return cls(fps, intr, [flows[bounds[t]:bounds[t + 1]] for t in range(n_frames)], **optional).validate()
        except ObservationError as exc:
            raise ObservationError(f"{path}: {exc}") from None

