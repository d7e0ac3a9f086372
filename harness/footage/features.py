"""Sparse features on each person: Shi-Tomasi corners inside the person's mask, followed from frame to frame by
pyramidal Lucas-Kanade with a forward-backward check, and re-detected every few frames.

A feature's flow row is ``(u, v, du, dv)``: its position in this frame and ``(p_t - p_{t-1}) * fps``, in the
pixel convention of ``harness.pinhole`` (pixel ``(i, j)`` covers ``[j, j+1) x [i, i+1)``; OpenCV puts pixel
centres at integers, so ``u = x_opencv + 0.5``). A feature is kept when Lucas-Kanade converges both ways, the
backward track returns within ``FB_MAX_PX`` of its start, and it ends on its person's foreground (a feature
that slid onto the background, or onto someone else, is dropped).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_CORNERS = 80         # per person: the default scene sees about 50-70 of its 100 markers, and the engine
                         # tempers a frame to a few flows' worth of evidence, so more adds time, not information
QUALITY = 0.01           # Shi-Tomasi: the weaker eigenvalue at least this share of the region's strongest
CANDIDATES = 4           # corners asked of Shi-Tomasi per corner wanted, for ``spread`` to choose from
GRID_ROWS = 8            # ``spread``'s cells: the person's box in 8 rows of square cells (head, chest, ..., feet)
MIN_DISTANCE_PX = 3      # px between corners (a 50 px tall person is about 15 px wide)
BLOCK_PX = 3             # Shi-Tomasi's neighbourhood
ERODE_PX = 4             # corners this far inside the mask (half the window): a window that holds background,
                         # which does not move with the person, pulls the flow towards zero (a 28 px patch moving
                         # 1.4 px/frame, 9x9 window: 77% of its features within 0.2 px with 2 px, 92% with 4)
KEEP_PX = 2              # a tracked feature may end this far outside its person's mask (the mask's own error)
LK_WINDOW = (9, 9)       # px: a limb of a 50-100 px person is 5-15 px wide; a larger window holds background
                         # (rendered cloth: median endpoint error 0.06-0.12 px with 7, 9 or 11)
LK_LEVELS = 3            # pyramid levels: up to 8 px per frame at the window's scale, 64 px at the top
FB_MAX_PX = 0.5          # px, forward-backward consistency (as rendered mode's dots: ``harness.scene.rendered``)
REDETECT_EVERY = 3       # frames between re-detections (also whenever a person holds fewer than MIN_POINTS)
MIN_POINTS = 20
_LK_CRITERIA = (3, 30, 0.01)     # cv2.TERM_CRITERIA_EPS | COUNT: 30 iterations or 0.01 px


def lucas_kanade(prev: np.ndarray, grey: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(N, 2)`` (OpenCV coordinates) of ``prev`` followed into ``grey``: their new positions ``(N, 2)``
    and whether each passed the forward-backward check ``(N,)``."""
    import cv2

    if len(points) == 0:
        return np.empty((0, 2)), np.empty(0, dtype=bool)
    lk = dict(winSize=LK_WINDOW, maxLevel=LK_LEVELS, criteria=_LK_CRITERIA)
    p0 = points.astype(np.float32).reshape(-1, 1, 2)
    p1, ok1, _ = cv2.calcOpticalFlowPyrLK(prev, grey, p0, None, **lk)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(grey, prev, p1, None, **lk)
    fb = np.linalg.norm(back.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
    good = (ok1.ravel() == 1) & (ok2.ravel() == 1) & (fb < FB_MAX_PX)
    return p1.reshape(-1, 2).astype(float), good


def corners(grey: np.ndarray, labels: np.ndarray, own: tuple[int, ...], box: np.ndarray, existing: np.ndarray,
            count: int) -> np.ndarray:
    """Up to ``count`` Shi-Tomasi corners ``(K, 2)`` (OpenCV coordinates) on the blobs ``own`` of the label image
    ``labels (H, W)``, their mask eroded by ``ERODE_PX``, within ``box`` (``x, y, w, h``), at least
    ``MIN_DISTANCE_PX`` from the ``existing (N, 2)`` points, spread over the person (``spread``). Only the box is
    searched (the whole image would cost ten times more)."""
    import cv2

    if count <= 0:
        return np.empty((0, 2))
    x, y, w, h = (int(v) for v in box)
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    x1, y1 = min(x + w + 1, grey.shape[1]), min(y + h + 1, grey.shape[0])
    if x1 - x0 < 3 or y1 - y0 < 3:
        return np.empty((0, 2))
    crop = np.isin(labels[y0:y1, x0:x1], own).astype(np.uint8) * 255
    crop = cv2.erode(crop, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ERODE_PX + 1, 2 * ERODE_PX + 1)))
    for px, py in np.round(existing).astype(int):
        cv2.circle(crop, (px - x0, py - y0), MIN_DISTANCE_PX, 0, -1)
    if not crop.any():
        return np.empty((0, 2))
    found = cv2.goodFeaturesToTrack(np.ascontiguousarray(grey[y0:y1, x0:x1]), maxCorners=CANDIDATES * int(count),
                                    qualityLevel=QUALITY, minDistance=MIN_DISTANCE_PX, mask=crop,
                                    blockSize=BLOCK_PX, useHarrisDetector=False)
    if found is None:
        return np.empty((0, 2))
    found = found.reshape(-1, 2).astype(float) + [x0, y0]
    return found[spread(found, existing, (x0, y0, x1 - x0, y1 - y0), count)]


def spread(candidates: np.ndarray, existing: np.ndarray, box: tuple, count: int) -> np.ndarray:
    """Indices of at most ``count`` of ``candidates (K, 2)`` (best first, as Shi-Tomasi returns them) spread over
    ``box``: the box is cut into square cells (``GRID_ROWS`` rows) and the cells are filled evenly, those holding
    fewer ``existing`` points first, each with its best corners.

    The engine expects flows from points spread over the visible body (its model points are area-uniform, as the
    harness's markers are); the strongest corners of a person cluster where the texture is boldest (a striped
    shirt), and without the cells the legs of the rendered subject got few features."""
    if len(candidates) == 0:
        return np.empty(0, dtype=int)
    x, y, w, h = box
    cell = max(h / GRID_ROWS, 1.0)
    cols = max(int(np.ceil(w / cell)), 1)

    def cell_of(p):
        return (np.clip(((p[:, 1] - y) // cell).astype(int), 0, GRID_ROWS - 1) * cols
                + np.clip(((p[:, 0] - x) // cell).astype(int), 0, cols - 1))

    c = cell_of(candidates)
    held = np.bincount(cell_of(existing), minlength=GRID_ROWS * cols) if len(existing) else \
        np.zeros(GRID_ROWS * cols, dtype=int)
    # Rank of each candidate within its cell (0: its cell's best), plus what the cell already holds: filling
    # level by level takes every cell's best before any cell's second.
    order = np.argsort(c, kind="stable")
    first = np.searchsorted(c[order], c[order])
    rank = np.empty(len(c), dtype=int)
    rank[order] = np.arange(len(c)) - first
    level = rank + held[c]
    return np.lexsort((np.arange(len(c)), level))[:count]


@dataclass(frozen=True)
class PersonView:
    """What the frame shows of one person: the blob labels that are theirs (empty when they are inside a
    group or unseen), and their box ``x, y, w, h``."""

    labels: tuple[int, ...]
    box: np.ndarray


class FeatureTracker:
    """Every person's features (state: the previous grey frame and each person's points)."""

    def __init__(self, fps: float):
        self.fps = float(fps)
        self.prev: np.ndarray | None = None
        self.points: dict[int, np.ndarray] = {}
        self.frame = -1

    def step(self, grey: np.ndarray, labels: np.ndarray, people: dict[int, PersonView]) -> dict[int, np.ndarray]:
        """Follow every person's features into ``grey (H, W) uint8``; ``labels``: the frame's blob label image
        (``harness.footage.foreground.Detections.labels``); ``people``: the people followed this frame. Returns
        each person's flows ``(M, 4)`` (``u, v`` px, ``du, dv`` px/s); people not in ``people`` are forgotten."""
        import cv2

        self.frame += 1
        self.points = {i: p for i, p in self.points.items() if i in people}
        flows: dict[int, np.ndarray] = {}
        near = cv2.dilate(labels.astype(np.uint16), np.ones((2 * KEEP_PX + 1, 2 * KEEP_PX + 1), np.uint8))
        if self.prev is not None and self.points:
            ids = list(self.points)
            start = np.concatenate([self.points[i] for i in ids])
            owner = np.repeat(np.arange(len(ids)), [len(self.points[i]) for i in ids])
            end, good = lucas_kanade(self.prev, grey, start)
            h, w = grey.shape
            inside = (end[:, 0] >= 0) & (end[:, 1] >= 0) & (end[:, 0] <= w - 1) & (end[:, 1] <= h - 1)
            good &= inside
            under = np.zeros(len(end), dtype=int)
            pix = np.round(end[inside]).astype(int)
            under[inside] = near[pix[:, 1], pix[:, 0]]
            for k, i in enumerate(ids):
                mine = good & (owner == k)
                own = people[i].labels
                # A person with blobs of their own keeps the features that end on them; a person inside a
                # group keeps those that end on the group's foreground.
                mine &= np.isin(under, own) if own else under > 0
                self.points[i] = end[mine]
                flows[i] = np.concatenate([end[mine] + 0.5, (end[mine] - start[mine]) * self.fps], axis=1)
        for i, view in people.items():
            have = self.points.get(i, np.empty((0, 2)))
            if view.labels and (self.frame % REDETECT_EVERY == 0 or len(have) < MIN_POINTS):
                new = corners(grey, labels, view.labels, view.box, have, MAX_CORNERS - len(have))
                have = np.concatenate([have, new]) if len(new) else have
            self.points[i] = have
            flows.setdefault(i, np.empty((0, 4)))
        self.prev = grey
        return flows
