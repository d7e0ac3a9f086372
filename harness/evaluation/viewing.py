"""The viewing conditions of one run, as columns of its rows: where the camera stood, drawn per run.

The default scenario draws the camera's azimuth at random per run, so its rows mix views from the front, the
side and the back; these columns let the tables and the report say how the engine fares from each:

| column | unit | meaning |
|---|---|---|
| ``view_azimuth_deg`` | deg, [-180, 180) | the camera about world z from the subject's initial heading (0: in front, seeing the face; 90: on its left; +-180: behind), as drawn for the run (for an orbiting camera, at the first frame) |
| ``view_elevation_deg`` | deg | the camera above the look-at point |
| ``view_distance_m`` | m | the camera from the look-at point |
| ``visible_markers`` | | markers visible per frame (in view, not hidden by the body or an obstacle), mean over frames |

They come from the run's scene spec with its per-run draws (``scenario.scene_spec``) and its ground truth; the
engine sees none of them.
"""

from __future__ import annotations

import numpy as np

from harness.scene.simulate import GroundTruth
from harness.scene.spec import SceneSpec
from harness.scene.visibility import VISIBLE

VIEW_COLUMNS = ("view_azimuth_deg", "view_elevation_deg", "view_distance_m", "visible_markers")
# |azimuth| bins: within 45 deg of seeing the face, within 45 deg of seeing the back, and the two sides.
VIEW_BINS = (("front", 0.0, 45.0), ("side", 45.0, 135.0), ("back", 135.0, 180.0))


def wrap_deg(angle: float | np.ndarray) -> float | np.ndarray:
    """Angles in degrees wrapped to [-180, 180)."""
    return (np.asarray(angle, dtype=float) + 180.0) % 360.0 - 180.0


def viewing_columns(spec: SceneSpec, truth: GroundTruth) -> dict:
    """The ``VIEW_COLUMNS`` of a run from its drawn scene spec and its ground truth."""
    visible = (np.asarray(truth.visibility) == VISIBLE).sum(axis=1)
    return {"view_azimuth_deg": float(wrap_deg(spec.camera.azimuth)),
            "view_elevation_deg": float(spec.camera.elevation),
            "view_distance_m": float(spec.camera.distance),
            "visible_markers": float(visible.mean()) if len(visible) else float("nan")}


def view_bin(azimuth_deg) -> np.ndarray:
    """``front``, ``side`` or ``back`` for azimuths (degrees, any range): ``VIEW_BINS`` of ``|wrap(azimuth)|``,
    each bin closed below (45 is a side view, 135 a back view); ``""`` for NaN."""
    a = np.abs(wrap_deg(azimuth_deg))
    out = np.full(a.shape, "", dtype=object)
    for name, lo, hi in VIEW_BINS:
        out[(a >= lo) & ((a < hi) | (hi == 180.0))] = name
    return out
