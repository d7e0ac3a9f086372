"""Rendered observations: MuJoCo images of the scene, bright marker dots detected and tracked with OpenCV.

Each frame is rendered offscreen from the scene camera with the markers drawn as small emissive green
spheres (``harness.scene.markers``) on a darker body. Dots are found in the "greenness" image
``G - max(R, B)`` (grey floor, reddish skin, bluish occluders and white highlights are all near zero or
negative) by thresholding and connected components; each dot's position is its greenness-weighted
centroid (sub-pixel). Flow: pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) on the greenness image
from the dots of frame ``t - 1``, kept when the backward track returns within ``FB_MAX_PX`` of the start
and the forward track ends within ``SNAP_PX`` of a dot detected at ``t``; that dot's centroid is the end
point, so the flow is a difference of two centroids.

Pixel convention: pixel ``(i, j)`` covers ``[j, j+1) x [i, i+1)`` in the ``harness.pinhole`` image
coordinates, so an array index ``k`` is the continuous coordinate ``k + 0.5``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import cv2
import mujoco
import numpy as np

from harness.scene.markers import DOT_GROUP
from harness.scene.occluders import OCCLUDER_GROUP
from harness.scene.visibility import VISIBLE

if TYPE_CHECKING:
    from harness.scene.simulate import SceneSetup

DOT_THRESHOLD = 60          # greenness (0..255) above which a pixel belongs to a dot
FB_MAX_PX = 0.5             # forward-backward Lucas-Kanade consistency, pixels
SNAP_PX = 2.0               # a tracked point must end this close to a detected dot, pixels
MATCH_PX = 3.0              # ground truth: a dot is marker i if it lies this close to its projection
MERGED_AREA = 3.0         # blob area, relative to the median, above which a blob is several dots
LK_WINDOW = (15, 15)
LK_LEVELS = 3


def scene_option(dots: bool) -> mujoco.MjvOption:
    """Render the body and the occluders; the marker dots only when ``dots``."""
    opt = mujoco.MjvOption()
    opt.geomgroup[OCCLUDER_GROUP] = 1
    opt.sitegroup[:] = 0
    if dots:
        opt.sitegroup[DOT_GROUP] = 1
    return opt


def render_frames(setup: "SceneSetup", qpos: np.ndarray, depth: bool = False, dots: bool = True,
                  scale: int = 1) -> Iterator[np.ndarray]:
    """Yield the camera's images: RGB ``(H, W, 3) uint8``, or depth ``(H, W)`` metres along the optical axis.

    ``scale`` renders ``scale`` times the camera's resolution (same field of view): pixel coordinates
    scale by the same factor.
    """
    scene, traj = setup.scene, setup.camera
    intr = traj.intrinsics
    quat = traj.mujoco_quat()
    opt = scene_option(dots)
    with mujoco.Renderer(scene.model, scale * intr.height, scale * intr.width) as renderer:
        if depth:
            renderer.enable_depth_rendering()
        for t in range(len(qpos)):
            scene.pose(qpos[t], traj.pos[t], quat[t])
            renderer.update_scene(scene.data, camera=scene.camera_id, scene_option=opt)
            # Shadows cost three quarters of the software-GL time and only darken the body further.
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
            yield renderer.render().copy()


def greenness(rgb: np.ndarray) -> np.ndarray:
    """``G - max(R, B)`` clipped to ``[0, 255]``: ``(H, W) uint8``."""
    rgb = rgb.astype(np.int16)
    return np.clip(rgb[..., 1] - np.maximum(rgb[..., 0], rgb[..., 2]), 0, 255).astype(np.uint8)


def detect_dots(green: np.ndarray) -> np.ndarray:
    """Sub-pixel centres ``(K, 2)`` (u, v pixels) of the bright dots in a greenness image.

    Blobs larger than ``MERGED_AREA`` times the frame's median blob area are two or more dots run together
    (their centroid is no dot's centre) and are left out.
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStats((green > DOT_THRESHOLD).astype(np.uint8),
                                                           connectivity=8)
    if n <= 1:
        return np.empty((0, 2))
    w = green.astype(float).ravel()
    lab = labels.ravel()
    rows, cols = np.indices(green.shape)
    mass = np.bincount(lab, weights=w, minlength=n)[1:]
    u = np.bincount(lab, weights=w * cols.ravel(), minlength=n)[1:] / mass
    v = np.bincount(lab, weights=w * rows.ravel(), minlength=n)[1:] / mass
    area = stats[1:, cv2.CC_STAT_AREA]
    single = area <= MERGED_AREA * np.median(area)
    return np.stack([u, v], axis=1)[single] + 0.5


def track_dots(prev_green: np.ndarray, green: np.ndarray, prev_dots: np.ndarray, dots: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Dots of the previous frame followed into this one: start points ``(M, 2)``, end dot indices ``(M,)``."""
    if len(prev_dots) == 0 or len(dots) == 0:
        return np.empty((0, 2)), np.empty(0, dtype=int)
    lk = dict(winSize=LK_WINDOW, maxLevel=LK_LEVELS,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    p0 = (prev_dots - 0.5).astype(np.float32).reshape(-1, 1, 2)       # OpenCV: pixel centres at integers
    p1, ok1, _ = cv2.calcOpticalFlowPyrLK(prev_green, green, p0, None, **lk)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(green, prev_green, p1, None, **lk)
    p1 = p1.reshape(-1, 2) + 0.5
    fb = np.linalg.norm(back.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
    good = (ok1.ravel() == 1) & (ok2.ravel() == 1) & (fb < FB_MAX_PX)
    dist = np.linalg.norm(p1[:, None, :] - dots[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    good &= dist[np.arange(len(p1)), nearest] < SNAP_PX
    # One end dot per track: when two tracks land on the same dot, the ambiguity drops both.
    counts = np.bincount(nearest[good], minlength=len(dots))
    good &= counts[nearest] == 1
    return prev_dots[good], nearest[good]


def match_markers(points: np.ndarray, pixels: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Marker index ``(M,)`` of each image point: the nearest visible projection within ``MATCH_PX``, else -1."""
    idx = np.flatnonzero(visible)
    if len(points) == 0 or len(idx) == 0:
        return np.full(len(points), -1, dtype=int)
    dist = np.linalg.norm(points[:, None, :] - pixels[idx][None, :, :], axis=2)
    best = dist.argmin(axis=1)
    return np.where(dist[np.arange(len(points)), best] < MATCH_PX, idx[best], -1)


def rendered_flows(setup: "SceneSetup", qpos: np.ndarray, fps: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame ``(rows (M, 4), marker ids (M,))`` from rendered images (unshuffled, no dropout)."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    prev_green, prev_dots = None, None
    visible = setup.visibility == VISIBLE
    for t, rgb in enumerate(render_frames(setup, qpos)):
        green = greenness(rgb)
        dots = detect_dots(green)
        if prev_green is None:
            out.append((np.empty((0, 4)), np.empty(0, dtype=int)))
        else:
            start, end = track_dots(prev_green, green, prev_dots, dots)
            p1 = dots[end]
            rows = np.concatenate([p1, (p1 - start) * fps], axis=1)
            out.append((rows, match_markers(p1, setup.pixels[t], visible[t])))
        prev_green, prev_dots = green, dots
    return out


def depth_visible(setup: "SceneSetup", qpos: np.ndarray, tolerance: float = 0.02, scale: int = 1) -> np.ndarray:
    """Visibility from the renderer's depth buffer, ``(T, N)`` bool (an independent check of ray casting).

    A marker in the image is visible when the rendered depth at its pixel is not smaller than its own
    depth minus ``tolerance`` metres (the surface around a pixel centre is not exactly at the marker).
    """
    intr = setup.camera.intrinsics
    out = np.zeros(setup.visibility.shape, dtype=bool)
    z = setup.marker_cam[..., 2]
    for t, depth in enumerate(render_frames(setup, qpos, depth=True, dots=False, scale=scale)):
        inside = setup.visibility[t] != 1
        idx = np.flatnonzero(inside)
        col = np.clip(np.floor(scale * setup.pixels[t, idx, 0]).astype(int), 0, scale * intr.width - 1)
        row = np.clip(np.floor(scale * setup.pixels[t, idx, 1]).astype(int), 0, scale * intr.height - 1)
        out[t, idx] = depth[row, col] >= z[t, idx] - tolerance
    return out
