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

import cv2
import mujoco
import numpy as np

from harness.scene.markers import DOT_GROUP
from harness.scene.occluders import OCCLUDER_GROUP
from harness.scene.setup import SceneSetup
from harness.scene.visibility import BODY_GROUP, VISIBLE

DOT_THRESHOLD = 60          # greenness (0..255) above which a pixel belongs to a dot
FB_MAX_PX = 0.5             # forward-backward Lucas-Kanade consistency, pixels
SNAP_PX = 2.0               # a tracked point must end this close to a detected dot, pixels
MATCH_PX = 3.0              # ground truth: a dot is marker i if it lies this close to its projection
MERGED_AREA = 3.0         # blob area, relative to the median, above which a blob is several dots
DEPTH_TOLERANCE = 5e-3     # m: buffer depth this far in front of the marker's tangent plane hides it
DEPTH_MARGIN = 0.02        # m: buffer depth this far behind the tangent plane sees past the marker
DEPTH_SCALE = 2            # depth check renders at this multiple of the camera resolution
# Acceptance requirement of rendered flows (docs/scene.md; benchmarks/scene_acceptance.py, tests): at least this
# fraction of the geometric flows recovered, with a median endpoint error of at most REQUIRED_MEDIAN_PX.
REQUIRED_RECOVERY = 0.9
REQUIRED_MEDIAN_PX = 0.5
LK_WINDOW = (9, 9)         # px: small enough that a neighbouring dot rarely shares the window
LK_LEVELS = 3


def scene_option(dots: bool, body: bool = True) -> mujoco.MjvOption:
    """Render the body (unless not ``body``: the empty scene) and the occluders; the marker dots only when
    ``dots``."""
    opt = mujoco.MjvOption()
    opt.geomgroup[OCCLUDER_GROUP] = 1
    opt.geomgroup[BODY_GROUP] = int(body)
    opt.sitegroup[:] = 0
    if dots:
        opt.sitegroup[DOT_GROUP] = 1
    return opt


def render_frames(setup: SceneSetup, qpos: np.ndarray, depth: bool = False, dots: bool = True,
                  scale: int = 1, body: bool = True) -> Iterator[np.ndarray]:
    """Yield the camera's images: RGB ``(H, W, 3) uint8``, or depth ``(H, W)`` metres along the optical axis.

    ``scale`` renders ``scale`` times the camera's resolution (same field of view): pixel coordinates
    scale by the same factor. Without ``body``, the scene as it is without the subject (an empty plate).
    """
    scene, traj = setup.scene, setup.camera
    intr = traj.intrinsics
    quat = traj.mujoco_quat()
    opt = scene_option(dots, body)
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


def rendered_flows(setup: SceneSetup, qpos: np.ndarray, fps: float) -> list[tuple[np.ndarray, np.ndarray]]:
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


def _tangent_plane_depth(intr, normal_cam: np.ndarray, point_cam: np.ndarray, centres: np.ndarray
                         ) -> np.ndarray:
    """Depth (m, along the optical axis) at which the rays through image points ``centres (M, 2)`` px meet
    the planes through ``point_cam (M, 3)`` with normals ``normal_cam (M, 3)`` (camera frame).

    The plane through ``p`` with normal ``n`` meets the ray ``lambda * d``, ``d = ((u - cx)/fx, (v - cy)/fy, 1)``,
    at ``lambda = (n . p) / (n . d)``, which is also its depth since ``d_z = 1``. Where the ray runs parallel to
    the plane (or meets it behind the camera) the marker's own depth is returned.
    """
    d = np.stack([(centres[:, 0] - intr.cx) / intr.fx, (centres[:, 1] - intr.cy) / intr.fy,
                  np.ones(len(centres))], axis=1)
    num = np.einsum("mi,mi->m", normal_cam, point_cam)
    den = np.einsum("mi,mi->m", normal_cam, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = num / den
    return np.where(np.isfinite(lam) & (lam > 0.0), lam, point_cam[:, 2])


def depth_visible(setup: SceneSetup, qpos: np.ndarray, tolerance: float = DEPTH_TOLERANCE,
                  scale: int = DEPTH_SCALE, margin: float = DEPTH_MARGIN) -> np.ndarray:
    """Visibility from the renderer's depth buffer, ``(T, N)`` bool (an independent check of ray casting).

    The rasteriser knows the nearest surface only at pixel centres, and a marker lies between four of them
    (the 2x2 pixel centres around its projection, at ``scale`` times the camera resolution). At each centre
    the depth the marker's own surface would have there is its tangent plane's depth along that pixel's ray
    (``_tangent_plane_depth``; for a convex geom the true surface is never nearer than that plane when the
    marker faces the camera). A centre whose buffer depth is beyond that plane by more than ``margin`` m
    sees past the marker's surface (background or a farther part: the marker is at its geom's outline) and
    says nothing about the marker; of the other centres the nearest to the projected marker decides:
    visible when its buffer depth is not smaller than the plane depth minus ``tolerance`` m, hidden
    otherwise. When all four see past the marker, nothing is in front of it: visible.
    """
    intr = setup.camera.intrinsics
    out = np.zeros(setup.visibility.shape, dtype=bool)
    normal_cam = np.einsum("tji,tnj->tni", setup.camera.rot, setup.marker_normal)
    offsets = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
    size = np.array([scale * intr.width, scale * intr.height])
    for t, depth in enumerate(render_frames(setup, qpos, depth=True, dots=False, scale=scale)):
        idx = np.flatnonzero(setup.visibility[t] != 1)
        px = scale * setup.pixels[t, idx]                                   # (M, 2) in the scaled image
        corner = np.floor(px - 0.5).astype(int)                             # pixel whose centre is up-left
        n_m = len(idx)
        sees = np.empty((4, n_m), dtype=bool)
        informative = np.empty((4, n_m), dtype=bool)
        dist2 = np.empty((4, n_m))
        for k, off in enumerate(offsets):
            pix = np.clip(corner + off, 0, size - 1)
            centre = pix + 0.5
            plane = _tangent_plane_depth(intr, normal_cam[t, idx], setup.marker_cam[t, idx], centre / scale)
            buf = depth[pix[:, 1], pix[:, 0]]
            sees[k] = buf >= plane - tolerance
            informative[k] = buf <= plane + margin
            dist2[k] = ((centre - px) ** 2).sum(axis=1)
        nearest = np.where(informative, dist2, np.inf).argmin(axis=0)
        out[t, idx] = np.where(informative.any(axis=0), sees[nearest, np.arange(n_m)], True)
    return out
