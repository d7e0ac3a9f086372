"""Offscreen rendering of the humanoid and video files (MP4 or GIF by extension), for people to look at.

``MUJOCO_GL=egl`` renders on the CPU through Mesa when there is no GPU (the Makefile sets it).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import mujoco
import numpy as np

from harness.errors import HarnessError
from harness.io import write_atomic


ARROW_SECONDS = 0.1     # a flow arrow shows the displacement over this time (px/s times seconds = px)


class VideoError(HarnessError):
    """A video that cannot be written."""


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float) -> int:
    """Write RGB frames ``(H, W, 3) uint8`` to ``.mp4`` (OpenCV, mp4v) or ``.gif`` (Pillow), atomically.

    Returns the number of frames written. MP4 frames are streamed (``Mp4Writer``); a GIF holds them all.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise VideoError(f"{path}: video files must end in .mp4 or .gif")
    if suffix == ".mp4":
        with Mp4Writer(path, fps) as writer:
            for f in frames:
                writer.write(f)
        if writer.count == 0:
            raise VideoError(f"{path}: no frames to write")
        return writer.count
    frames = list(frames)
    if not frames:
        raise VideoError(f"{path}: no frames to write")
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]

    def write(fh):
        images[0].save(fh, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(round(1000.0 / fps)), loop=0)
    write_atomic(path, write)
    return len(frames)


class Mp4Writer:
    """An MP4 file written frame by frame (OpenCV, mp4v), so that a long video never sits in memory; atomic:
    frames go to a hidden temporary file beside ``path``, renamed to ``path`` when the ``with`` block ends
    without an error and at least one frame was written (else the temporary file is removed).

    ``write(rgb)`` takes ``(H, W, 3) uint8`` RGB frames of one size; ``count`` frames were written.
    """

    def __init__(self, path: str | Path, fps: float):
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise VideoError(f"{self.path}: an MP4 writer's file must end in .mp4")
        self.fps = float(fps)
        self.tmp = self.path.with_name(f".{self.path.stem}.tmp.mp4")
        self.writer = None
        self.size: tuple[int, int] | None = None
        self.count = 0

    def __enter__(self) -> "Mp4Writer":
        return self

    def write(self, rgb: np.ndarray) -> None:
        import cv2

        h, w = rgb.shape[:2]
        if self.writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = cv2.VideoWriter(str(self.tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (w, h))
            if not self.writer.isOpened():
                raise VideoError(f"{self.path}: OpenCV cannot open an MP4 writer")
            self.size = (w, h)
        elif (w, h) != self.size:
            raise VideoError(f"{self.path}: frame {self.count} is {w}x{h}, the video {self.size[0]}x{self.size[1]}")
        self.writer.write(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
        self.count += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.writer is not None:
            self.writer.release()
        if exc_type is None and self.count > 0:
            os.replace(self.tmp, self.path)
        elif self.tmp.exists():
            self.tmp.unlink()


def add_spheres(scene: mujoco.MjvScene, centres: np.ndarray, radius: float, rgba) -> None:
    """Append small spheres (decoration only, not part of the model) to a scene about to be rendered."""
    for c in np.asarray(centres, dtype=float).reshape(-1, 3):
        if scene.ngeom >= scene.maxgeom:
            return
        mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, np.array([radius, 0, 0]),
                            c, np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32))
        scene.ngeom += 1


def render_motion(model: mujoco.MjModel, qpos: np.ndarray, width: int = 480, height: int = 480,
                  distance: float = 4.0, azimuth: float = 150.0, elevation: float = -12.0,
                  follow: bool = True, spheres: np.ndarray | None = None, sphere_radius: float = 0.025,
                  sphere_rgba=(0.1, 0.8, 1.0, 1.0)) -> Iterator[np.ndarray]:
    """Yield RGB frames of configurations ``qpos (T, 57)`` seen by a free camera.

    The camera looks at the pelvis (``follow``) or at the first frame's pelvis; azimuth and elevation are
    MuJoCo's free-camera angles in degrees. ``spheres`` ``(T, K, 3)`` are drawn as extra world-frame dots
    (for example a source skeleton's joints beside the retargeted body).
    """
    data = mujoco.MjData(model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    start = np.asarray(qpos)[0, :3]
    with mujoco.Renderer(model, height, width) as renderer:
        for t, q in enumerate(np.asarray(qpos)):
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            cam.lookat[:] = [q[0], q[1], 0.9] if follow else [start[0], start[1], 0.9]
            renderer.update_scene(data, cam)
            if spheres is not None:
                add_spheres(renderer.scene, spheres[t], sphere_radius, sphere_rgba)
            yield renderer.render().copy()


def draw_flows(rgb: np.ndarray, flows: np.ndarray, outlier: np.ndarray | None = None) -> np.ndarray:
    """Arrows from ``p - flow * ARROW_SECONDS`` to ``p`` for rows ``(u, v, du, dv)``; a new RGB image."""
    import cv2

    img = np.ascontiguousarray(rgb.copy())
    for k, (u, v, du, dv) in enumerate(flows):
        colour = (255, 60, 60) if outlier is not None and outlier[k] else (255, 230, 0)
        start = (int(round(u - du * ARROW_SECONDS)), int(round(v - dv * ARROW_SECONDS)))
        cv2.arrowedLine(img, start, (int(round(u)), int(round(v))), colour, 1, cv2.LINE_AA, tipLength=0.3)
    return img


def draw_skeleton(img: np.ndarray, uv: np.ndarray, parents: np.ndarray, rgb, front: np.ndarray,
                  thickness: int = 2) -> None:
    """Draw joints ``uv (J, 2)`` px joined parent to child (``parents (J,)``, -1 for a root) on ``img`` in
    place; joints not in ``front (J,)`` (behind the camera) are left out."""
    import cv2

    pts = np.round(uv).astype(int)
    for j, p in enumerate(parents):
        if p >= 0 and front[j] and front[p]:
            cv2.line(img, tuple(pts[p]), tuple(pts[j]), rgb, thickness, cv2.LINE_AA)
    for j in np.flatnonzero(front):
        cv2.circle(img, tuple(pts[j]), thickness + 1, rgb, -1, cv2.LINE_AA)
