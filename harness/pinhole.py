"""The pinhole camera: intrinsics, perspective projection, and its Jacobian.

Camera frame (OpenCV convention): x right, y down, z forward along the optical axis; a point ``X`` in
front of the camera has ``Z > 0``. Pixel ``(u, v)`` = ``(fx X / Z + cx, fy Y / Z + cy)``, origin at the
top-left corner of the image, u to the right, v down. MuJoCo cameras look along their -z with y up:
``X_opencv = diag(1, -1, -1) X_mujoco``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.errors import HarnessError

MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
MAX_IMAGE_SIDE = 8192          # px: an image side beyond this is a typo or a corrupt file (a rendered frame of
                               # 8192 x 8192 is already 200 MB), not a camera
FOCAL_RANGE_PX = (0.1, 1e7)    # focal lengths outside this make projections degenerate (a 170 deg field of view
                               # on a 16 px image is 0.7 px)
MAX_PRINCIPAL_PX = 1e7


class CameraError(HarnessError):
    """Camera parameters that cannot describe an image."""


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics: image size (pixels), focal lengths and principal point (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0:
            raise CameraError(f"image size must be positive, got {self.width}x{self.height}")
        if self.width > MAX_IMAGE_SIDE or self.height > MAX_IMAGE_SIDE:
            raise CameraError(f"image size {self.width}x{self.height} is larger than {MAX_IMAGE_SIDE} px a side")
        if not (self.fx > 0 and self.fy > 0):
            raise CameraError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        lo, hi = FOCAL_RANGE_PX
        if not (lo <= self.fx <= hi and lo <= self.fy <= hi):
            raise CameraError(f"focal lengths must be in [{lo:g}, {hi:g}] px, got fx={self.fx}, fy={self.fy}")
        if not (abs(self.cx) <= MAX_PRINCIPAL_PX and abs(self.cy) <= MAX_PRINCIPAL_PX):
            raise CameraError(f"principal point must be finite, within {MAX_PRINCIPAL_PX:g} px, got "
                              f"({self.cx}, {self.cy})")

    @classmethod
    def from_fov(cls, fovy_deg: float, width: int, height: int) -> "Intrinsics":
        """Square pixels, principal point at the image centre, vertical field of view ``fovy_deg``.

        Matches MuJoCo's camera model (``cam_fovy`` is the vertical field of view).
        """
        if not 0.0 < fovy_deg < 180.0:
            raise CameraError(f"field of view must be in (0, 180) degrees, got {fovy_deg}")
        if width <= 0 or height <= 0:
            raise CameraError(f"image size must be positive, got {width}x{height}")
        f = 0.5 * height / np.tan(0.5 * np.deg2rad(fovy_deg))
        return cls(int(width), int(height), f, f, 0.5 * width, 0.5 * height)

    def as_array(self) -> np.ndarray:
        """``[width, height, fx, fy, cx, cy]`` (the form stored in observation files)."""
        return np.array([self.width, self.height, self.fx, self.fy, self.cx, self.cy], dtype=float)

    @classmethod
    def from_array(cls, a) -> "Intrinsics":
        a = np.asarray(a)
        if a.dtype.kind not in "iuf":
            raise CameraError(f"intrinsics must be real numbers, got dtype {a.dtype}")
        a = a.astype(float).ravel()
        if a.shape != (6,):
            raise CameraError(f"intrinsics need 6 numbers [width, height, fx, fy, cx, cy], got {a.shape[0]}")
        if not np.isfinite(a).all():
            raise CameraError("intrinsics must be finite numbers [width, height, fx, fy, cx, cy]")
        if not (1 <= a[0] <= MAX_IMAGE_SIDE and 1 <= a[1] <= MAX_IMAGE_SIDE) or a[0] != round(a[0]) \
                or a[1] != round(a[1]):
            raise CameraError(f"image size must be whole pixels in [1, {MAX_IMAGE_SIDE}], got {a[0]:g}x{a[1]:g}")
        return cls(int(round(a[0])), int(round(a[1])), float(a[2]), float(a[3]), float(a[4]), float(a[5]))

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def project(intr: Intrinsics, points: np.ndarray) -> np.ndarray:
    """Pixels ``(..., 2)`` of camera-frame points ``(..., 3)`` (no check that Z > 0)."""
    points = np.asarray(points, dtype=float)
    inv_z = 1.0 / points[..., 2]
    return np.stack([intr.fx * points[..., 0] * inv_z + intr.cx,
                     intr.fy * points[..., 1] * inv_z + intr.cy], axis=-1)


def projection_jacobian(intr: Intrinsics, points: np.ndarray) -> np.ndarray:
    """``d(u, v) / d(X, Y, Z)``: ``(..., 2, 3)`` pixels per metre.

    ``[[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]]``; it also maps a camera-frame velocity to pixels/s.
    """
    points = np.asarray(points, dtype=float)
    inv_z = 1.0 / points[..., 2]
    zero = np.zeros_like(inv_z)
    row_u = np.stack([intr.fx * inv_z, zero, -intr.fx * points[..., 0] * inv_z**2], axis=-1)
    row_v = np.stack([zero, intr.fy * inv_z, -intr.fy * points[..., 1] * inv_z**2], axis=-1)
    return np.stack([row_u, row_v], axis=-2)


def in_image(intr: Intrinsics, pixels: np.ndarray) -> np.ndarray:
    """Whether pixels ``(..., 2)`` fall inside the image ``[0, width) x [0, height)``."""
    pixels = np.asarray(pixels, dtype=float)
    return ((pixels[..., 0] >= 0) & (pixels[..., 0] < intr.width)
            & (pixels[..., 1] >= 0) & (pixels[..., 1] < intr.height))
