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
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.errors import HarnessError
from harness.io import save_npz_atomic
from harness.pinhole import Intrinsics


def _why(exc: Exception) -> str:
    """A file-format failure in words, without quoting the file's content."""
    if isinstance(exc, EOFError) or (isinstance(exc, OSError) and not isinstance(exc, zipfile.BadZipFile)):
        return "empty or truncated"
    if isinstance(exc, zipfile.BadZipFile):
        return "not an .npz archive or truncated"
    return f"malformed arrays: {type(exc).__name__}"


MAX_FRAMES = 10_000_000     # a larger frame count is a corrupt file, not a recording


class ObservationError(HarnessError):
    """Observations that the engine cannot use (NaN, outside the image, malformed file)."""


@dataclass
class Observation:
    """A sequence of unlabeled flow sets seen by one camera.

    fps: frames per second. intrinsics: the camera's pinhole intrinsics.
    flows: list of ``T`` arrays ``(M_t, 4)``: ``u, v`` (pixels), ``du, dv`` (pixels/s).
    camera_motion: ``(T, 6)`` camera velocity (linear m/s, angular rad/s, camera frame) or None (static).
    """

    fps: float
    intrinsics: Intrinsics
    flows: list[np.ndarray]
    camera_motion: np.ndarray | None = None

    def __post_init__(self):
        self.flows = [np.asarray(f, dtype=float).reshape(-1, 4) for f in self.flows]
        if self.camera_motion is not None:
            self.camera_motion = np.asarray(self.camera_motion, dtype=float)

    def __len__(self) -> int:
        return len(self.flows)

    @property
    def counts(self) -> np.ndarray:
        return np.array([len(f) for f in self.flows], dtype=int)

    def validate(self) -> "Observation":
        """Raise ``ObservationError`` naming the frame, row and problem; return self when usable."""
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ObservationError(f"fps must be a positive number, got {self.fps}")
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
        if self.camera_motion is not None:
            if self.camera_motion.shape != (len(self.flows), 6):
                raise ObservationError(f"camera_motion must have shape ({len(self.flows)}, 6), "
                                       f"got {self.camera_motion.shape}")
            if not np.isfinite(self.camera_motion).all():
                raise ObservationError("camera_motion has NaN or infinite values")
        return self

    def save(self, path: str | Path) -> None:
        """Write the documented ``.npz`` format atomically."""
        arrays = {
            "flows": np.concatenate(self.flows) if self.flows else np.empty((0, 4)),
            "frame": np.repeat(np.arange(len(self.flows)), self.counts),
            "n_frames": np.array(len(self.flows)),
            "fps": np.array(float(self.fps)),
            "intrinsics": self.intrinsics.as_array(),
        }
        if self.camera_motion is not None:
            arrays["camera_motion"] = self.camera_motion
        save_npz_atomic(path, arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Observation":
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                flows, frame = np.asarray(z["flows"], float), np.asarray(z["frame"], int)
                n_frames, fps = int(z["n_frames"]), float(z["fps"])
                intr = Intrinsics.from_array(z["intrinsics"])
                motion = np.asarray(z["camera_motion"], float) if "camera_motion" in z.files else None
        except FileNotFoundError:
            raise ObservationError(f"{path}: no such observation file") from None
        except KeyError as exc:
            raise ObservationError(f"{path}: not an observation file (no array {exc.args[0]!r})") from None
        except (ValueError, TypeError, IndexError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # Empty, truncated or foreign files: name the kind of failure, never the file's bytes.
            raise ObservationError(f"{path}: not an observation file ({_why(exc)})") from None
        except HarnessError as exc:        # intrinsics that describe no camera
            raise ObservationError(f"{path}: {exc}") from None
        if n_frames < 0 or n_frames > MAX_FRAMES:
            raise ObservationError(f"{path}: 'n_frames' must be in [0, {MAX_FRAMES}], got {n_frames}")
        if flows.ndim != 2 or flows.shape[1] != 4 or frame.ndim != 1 or len(frame) != len(flows):
            raise ObservationError(f"{path}: 'flows' must be (N, 4) with one 'frame' index per row")
        if len(frame) and (frame.min() < 0 or frame.max() >= n_frames or np.any(np.diff(frame) < 0)):
            raise ObservationError(f"{path}: 'frame' indices must be non-decreasing and in [0, n_frames)")
        bounds = np.searchsorted(frame, np.arange(n_frames + 1))
        try:
            return cls(fps, intr, [flows[bounds[t]:bounds[t + 1]] for t in range(n_frames)], motion).validate()
        except ObservationError as exc:
            raise ObservationError(f"{path}: {exc}") from None

