"""Feet on the floor: the base height and horizontal steps that ground a pose sequence.

For configurations given by their angles ``(T, 50)`` and base orientations ``(T, 4)`` (world from base, z up,
floor at z = 0), ``ground`` returns

- ``height (T,)``: the base height that puts the lowest point of the foot and toe geoms on the floor;
- ``steps (T-1, 2)``: the base's horizontal displacement between frames that keeps the supporting foot still,
  support passing from one foot to the other by ``sigmoid((z_right - z_left) / CONTACT_BLEND)`` (the lower
  foot carries the body).

This is the grounded-frame rule of the procedural performer (``harness.motion.performer.place_base``; a test
checks that both give the same base for a grounded motion). Streams use it to blend primitives and the
engine's reproduction to put a generated motion, of any body scale, on the floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from harness.body.kinematics import forward_points, geom_z_range
from harness.body.model import BodyModel
from harness.errors import BodyError

FOOT_GEOMS = ("lfoot", "ltoes", "rfoot", "rtoes")
CONTACT_BLEND = 0.01        # m, height difference over which support passes from one foot to the other
_REFERENCE_HEIGHT = 0.95    # m, any base height works: the results do not depend on it


@dataclass(frozen=True)
class Grounding:
    """``height (T,)`` m: base height with the lowest foot point on the floor. ``steps (T-1, 2)`` m: base xy
    displacement that keeps the supporting foot still. ``support_left (T,)``: weight of the left foot."""

    height: np.ndarray
    steps: np.ndarray
    support_left: np.ndarray

    def positions(self, start_xy: np.ndarray | None = None) -> np.ndarray:
        """Base positions ``(T, 3)``: the steps summed from ``start_xy`` (default the origin), at ``height``."""
        start = np.zeros(2) if start_xy is None else np.asarray(start_xy, dtype=float)
        xy = start + np.concatenate([np.zeros((1, 2)), np.cumsum(self.steps, axis=0)])
        return np.column_stack([xy, self.height])


def foot_geoms(body: BodyModel) -> np.ndarray:
    """Geom ids of the left foot, left toes, right foot and right toes."""
    ids = np.array([mujoco.mj_name2id(body.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in FOOT_GEOMS])
    if np.any(ids < 0):
        missing = [g for g, i in zip(FOOT_GEOMS, ids) if i < 0]
        raise BodyError(f"the body has no foot geom named {', '.join(missing)}")
    return ids


def ground(body: BodyModel, angles: np.ndarray, quats: np.ndarray) -> Grounding:
    """Ground the poses ``angles (T, 50)`` rad with base orientations ``quats (T, 4)`` (see the module doc)."""
    angles = np.asarray(angles, dtype=float)
    quats = np.asarray(quats, dtype=float)
    m = body.model
    geoms = foot_geoms(body)
    q = body.qpos(angles, base_pos=np.array([0.0, 0.0, _REFERENCE_HEIGHT]), base_quat=quats)
    low = geom_z_range(body, q, geoms)[:, :, 0]                       # (T, 4) lowest z per geom
    z_left, z_right = low[:, :2].min(axis=1), low[:, 2:].min(axis=1)
    soles = forward_points(body, q, m.geom_bodyid[geoms[[0, 2]]], m.geom_pos[geoms[[0, 2]]])[:, :, :2]
    left = 1.0 / (1.0 + np.exp(-np.clip((z_right - z_left) / CONTACT_BLEND, -50, 50)))
    mid = 0.5 * (left[1:] + left[:-1])[:, None]
    d = np.diff(soles, axis=0)                                        # (T-1, 2 feet, 2) relative to the base
    steps = -(mid * d[:, 0] + (1.0 - mid) * d[:, 1])
    return Grounding(_REFERENCE_HEIGHT - np.minimum(z_left, z_right), steps, left)
