"""Descriptors of a window of unlabeled flows: what the camera saw, nothing else (no marker identities, no pose).

Per frame ``t`` with at least ``MIN_FLOWS`` flows ``(u, v, du, dv)`` (px, px/s), velocities are divided by the
body's image height ``h`` (the spread of ``v`` between its 5th and 95th percentiles), so that the descriptors do
not depend on the camera's distance: speeds in body heights per second. ``FRAME_FEATURES`` per frame:

- median and 90th percentile of the flow speed; mean absolute horizontal and vertical velocity;
- mean signed vertical velocity (image y points down) and the velocity of the flows' centroid (u and v);
- median speed of the upper and of the lower third of the body (arms and head against legs);
- the width of the point spread over its height.

A window (frames ``0..t``, what a causal method has seen at ``t``) is described by the mean and the standard
deviation of each per-frame feature over its frames with enough flows: ``2 x FRAME_FEATURES`` numbers.
"""

from __future__ import annotations

import numpy as np

MIN_FLOWS = 5            # fewer flows than this tell nothing of the body's extent
FRAME_FEATURES = 10
NAMES = ("speed_median", "speed_p90", "abs_du", "abs_dv", "dv", "centroid_du", "centroid_dv", "speed_upper",
         "speed_lower", "aspect")


def frame_features(flows: list[np.ndarray]) -> np.ndarray:
    """``(T, FRAME_FEATURES)``, NaN for a frame with fewer than ``MIN_FLOWS`` flows."""
    out = np.full((len(flows), FRAME_FEATURES), np.nan)
    for t, f in enumerate(flows):
        f = np.asarray(f, dtype=float).reshape(-1, 4)
        if len(f) < MIN_FLOWS:
            continue
        u, v, du, dv = f.T
        lo, hi = np.percentile(v, [5, 95])
        h = max(hi - lo, 1.0)                                    # px; a degenerate spread is one pixel
        speed = np.hypot(du, dv) / h
        upper, lower = v < lo + (hi - lo) / 3, v > hi - (hi - lo) / 3
        width = np.subtract(*np.percentile(u, [95, 5]))
        out[t] = (np.median(speed), np.percentile(speed, 90), np.mean(np.abs(du)) / h, np.mean(np.abs(dv)) / h,
                  np.mean(dv) / h, np.mean(du) / h, np.mean(dv) / h,
                  np.median(speed[upper]) if upper.any() else np.nan,
                  np.median(speed[lower]) if lower.any() else np.nan, width / h)
    return out


def window_descriptors(flows: list[np.ndarray]) -> np.ndarray:
    """``(T, 2 x FRAME_FEATURES)``: row ``t`` describes frames ``0..t`` (mean and standard deviation of each
    per-frame feature over the frames that have it); NaN where no frame so far has it."""
    x = frame_features(flows)
    valid = np.isfinite(x)
    n = np.cumsum(valid, axis=0)
    s = np.cumsum(np.where(valid, x, 0.0), axis=0)
    s2 = np.cumsum(np.where(valid, x * x, 0.0), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s / n
        std = np.sqrt(np.maximum(s2 / n - mean ** 2, 0.0))
    mean[n == 0] = np.nan
    std[n == 0] = np.nan
    return np.concatenate([mean, std], axis=1)
