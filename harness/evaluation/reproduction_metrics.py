"""Scores of a reproduction against the demonstration it reproduces, after dynamic time warping.

A reproduction follows the demonstration's timing only as well as the recovered state path does; what is
compared is the motion, so both sequences are aligned by dynamic time warping (DTW: the monotone alignment of
frames, steps (1, 0), (0, 1) and (1, 1), that minimises the summed frame distance; Sakoe and Chiba, IEEE Trans.
ASSP 1978) before they are compared:

- ``dtw_deg``: joint-angle RMS (degrees, differences wrapped to +-180) over the aligned frame pairs, aligned
  on the mean squared angle difference;
- ``dtw_mm``: mean per-joint position error (millimetres) of the joint centres in the pelvis frame (the pose
  alone, as ``metrics.mpjpe_pose_mm``; the root left out), aligned on that error.
"""

from __future__ import annotations

import numpy as np

from harness.body import BodyModel, body_origins
from harness.evaluation.metrics import MetricError


def dtw_path(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The minimum-cost monotone alignment of a frame-distance matrix ``(N, M)``: frame indices ``(L,)`` into
    each sequence, from ``(0, 0)`` to ``(N - 1, M - 1)``."""
    cost = np.asarray(cost, dtype=float)
    n, m = cost.shape
    if n == 0 or m == 0:
        raise MetricError(f"DTW needs two non-empty sequences, got a {cost.shape} cost matrix")
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0
    for i in range(1, n + 1):
        row, prev = acc[i], acc[i - 1]
        for j in range(1, m + 1):
            row[j] = cost[i - 1, j - 1] + min(prev[j - 1], prev[j], row[j - 1])
    i, j = n, m
    path = [(i - 1, j - 1)]
    while (i, j) != (1, 1):
        moves = ((acc[i - 1, j - 1], i - 1, j - 1), (acc[i - 1, j], i - 1, j), (acc[i, j - 1], i, j - 1))
        _, i, j = min(moves, key=lambda x: x[0])
        path.append((i - 1, j - 1))
    a, b = np.array(path[::-1]).T
    return a, b


def _wrapped(d: np.ndarray) -> np.ndarray:
    return (d + np.pi) % (2 * np.pi) - np.pi


def dtw_angle_rms_deg(angles_a: np.ndarray, angles_b: np.ndarray) -> float:
    """Joint-angle RMS (degrees) of two angle sequences ``(N, 50)``, ``(M, 50)`` after DTW."""
    a, b = np.asarray(angles_a, dtype=float), np.asarray(angles_b, dtype=float)
    cost = np.mean(_wrapped(a[:, None, :] - b[None, :, :]) ** 2, axis=-1)
    i, j = dtw_path(cost)
    return float(np.rad2deg(np.sqrt(np.mean(cost[i, j]))))


def dtw_mpjpe_mm(body_a: BodyModel, qpos_a: np.ndarray, body_b: BodyModel, qpos_b: np.ndarray) -> float:
    """Mean per-joint position error (mm) of the pelvis-frame joint centres of two configuration sequences
    (each on its own body) after DTW."""
    pa = body_origins(body_a, qpos_a, frame="base")[:, 1:]
    pb = body_origins(body_b, qpos_b, frame="base")[:, 1:]
    cost = np.mean(np.linalg.norm(pa[:, None] - pb[None, :], axis=-1), axis=-1)
    i, j = dtw_path(cost)
    return float(1000.0 * np.mean(cost[i, j]))
