"""Moving people as foreground: OpenCV's Gaussian-mixture background subtractor (MOG2), its shadows and small
blobs removed, and the blobs that remain as detections.

The background is learned before the pass that follows people (``Foreground.learn``): from an empty plate
when one exists (rendered footage), else from frames spread over the whole clip, starting from their median, so
that the first frames have no ghosts of people who stood there at the start. During the pass the model keeps adapting slowly: a
person who stands still for ``ABSORB_S`` seconds fades into the background (MOG2 moves a pixel's new colour
into the background once its weight passes ``1 - background ratio``, 0.1 by default; at learning rate ``a``
that takes ``ln(1 / 0.9) / a`` frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

VAR_THRESHOLD = 25.0     # squared Mahalanobis distance a pixel must be from the background (OpenCV default 16:
                         # compressed real footage flickers more than that around edges)
SHADOW_VALUE = 127       # MOG2 marks shadow pixels with this value: they are not the person
LEARN_HISTORY = 100      # frames the background is learned from before the pass (a clip's frames spread evenly)
NOISE_FRAMES = 20        # ... of which this many, every NOISE_STRIDE-th pixel, measure the pixels' noise
NOISE_STRIDE = 4
MOVER_SIGMAS = 8.0       # a pixel this many noise deviations from the median is someone passing by (light drifting
                         # 5% over a clip, 8 grey levels, stays below it at the usual 2-3 levels of noise)
ABSORB_S = 10.0          # s a motionless person takes to become background during the pass
CLOSE_PX = 7             # px, elliptical closing: joins a person's parts split by a thin post or a gap in the mask
OPEN_PX = 3              # px, opening: removes speckle of compression noise
MIN_AREA_PX = 150        # px^2: smaller blobs are noise, leaves or a hand seen apart (a 50 px person is ~600)
MIN_HEIGHT_PX = 16       # px: a person shorter than this in the image carries too few features to track


@dataclass(frozen=True)
class Detections:
    """The foreground blobs of one frame: boxes ``(K, 4)`` int ``x, y, w, h`` (pixels, OpenCV's array
    coordinates), their pixel areas ``(K,)``, and a label image ``(H, W)`` int32 where blob ``k`` is ``k + 1``
    (0: background or a blob left out)."""

    boxes: np.ndarray
    areas: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return len(self.boxes)

    def mask(self, k: int) -> np.ndarray:
        """Blob ``k`` as an ``(H, W) uint8`` mask (255 inside)."""
        return np.where(self.labels == k + 1, 255, 0).astype(np.uint8)


class Foreground:
    """The background model of one static camera (state: the MOG2 subtractor)."""

    def __init__(self, fps: float, var_threshold: float = VAR_THRESHOLD, absorb_s: float = ABSORB_S):
        import cv2

        self.subtractor = cv2.createBackgroundSubtractorMOG2(history=LEARN_HISTORY, varThreshold=var_threshold,
                                                             detectShadows=True)
        # The learning rate at which a motionless pixel becomes background after absorb_s seconds.
        self.rate = math.log(1.0 / 0.9) / max(absorb_s * fps, 1.0)

    def learn(self, frames: list[np.ndarray]) -> None:
        """Learn the background from ``frames`` (an empty plate, or frames spread over the clip).

        MOG2 starts from the frames' per-pixel median (the empty scene wherever people pass by in less than half
        of them), then learns from every frame how each pixel varies (noise, light that drifts), except where a
        frame departs from the median by more than ``MOVER_SIGMAS`` times the pixels' noise (the median absolute
        deviation over all pixels): there the median stands in, so that nobody who walks by enters the model. Fed
        the frames as they are, MOG2 would keep whatever covers a pixel a tenth of the time as a second
        background colour, a person who walks slowly across a short clip among them."""
        import cv2

        if not frames:
            return
        stack = np.stack(frames)
        plate = np.partition(stack, len(stack) // 2, axis=0)[len(stack) // 2]
        sample = stack[:NOISE_FRAMES, ::NOISE_STRIDE, ::NOISE_STRIDE].astype(np.int16)
        sigma = max(1.4826 * float(np.median(np.abs(sample - plate[::NOISE_STRIDE, ::NOISE_STRIDE]))), 1.0)
        self.subtractor.setVarInit(float(np.clip(sigma**2, self.subtractor.getVarMin(),
                                                 self.subtractor.getVarMax())))
        self.subtractor.apply(plate, learningRate=1.0)
        grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CLOSE_PX, CLOSE_PX))
        for frame in frames:
            departs = np.abs(frame.astype(np.int16) - plate).max(axis=2) > MOVER_SIGMAS * sigma
            mover = cv2.dilate(departs.astype(np.uint8), grow).astype(bool)
            self.subtractor.apply(np.where(mover[..., None], plate, frame), learningRate=-1)

    def mask(self, frame: np.ndarray) -> np.ndarray:
        """The frame's foreground ``(H, W) uint8`` (255 moving, 0 background), shadows removed, cleaned."""
        import cv2

        raw = self.subtractor.apply(frame, learningRate=self.rate)
        fg = np.where(raw > SHADOW_VALUE, 255, 0).astype(np.uint8)
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (OPEN_PX, OPEN_PX)))
        return cv2.morphologyEx(fg, cv2.MORPH_CLOSE,
                                cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CLOSE_PX, CLOSE_PX)))


def blobs(mask: np.ndarray, min_area: int = MIN_AREA_PX, min_height: int = MIN_HEIGHT_PX) -> Detections:
    """The connected blobs of a foreground mask ``(H, W) uint8`` of at least ``min_area`` pixels and
    ``min_height`` rows, relabelled ``1..K`` in OpenCV's order (top to bottom, left to right)."""
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = np.flatnonzero((stats[1:, cv2.CC_STAT_AREA] >= min_area)
                          & (stats[1:, cv2.CC_STAT_HEIGHT] >= min_height)) + 1
    relabel = np.zeros(n, dtype=np.int32)
    relabel[keep] = np.arange(1, len(keep) + 1)
    boxes = stats[keep][:, [cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT]]
    return Detections(boxes.astype(int).reshape(-1, 4), stats[keep, cv2.CC_STAT_AREA].astype(int),
                      relabel[labels])
