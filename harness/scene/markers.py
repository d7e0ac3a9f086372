"""Unlabeled markers: random surface points of the humanoid, added to a model as sites.

Placement is area-uniform over the exposed body surface (``harness.body.sample_surface``) from the
marker seed alone, so that the same ``MarkerSpec`` gives the same markers in every scene. In the scene
model each marker is a site ``marker<i>`` on its body; sites are invisible to ray casting (``mj_ray``
only meets geoms) and are drawn by the renderer as small bright dots (group ``DOT_GROUP``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from harness.body import BodyModel, SurfacePoints, sample_surface
from harness.scene.spec import MarkerSpec

DOT_GROUP = 5                       # site group of the rendered dots (enabled only when rendering dots)
DOT_RADIUS = 0.012                  # m: about 1.7 px at 4 m with a 640x480, 45 degree camera
DOT_RGBA = (0.0, 1.0, 0.0, 1.0)     # pure green, emissive: stands out from grey floor and reddish skin
BODY_RGBA = (0.30, 0.22, 0.20, 1.0)  # a darker skin for rendered scenes, so that the dots dominate


def sample_markers(body: BodyModel, spec: MarkerSpec) -> SurfacePoints:
    """``spec.count`` area-uniform surface points, deterministic for ``spec.seed``."""
    return sample_surface(body, spec.count, np.random.default_rng(spec.seed))


def add_marker_sites(mjspec: mujoco.MjSpec, body: BodyModel, markers: SurfacePoints) -> None:
    """Add one emissive sphere site per marker to the bodies of a model being built (named ``marker<i>``)."""
    mjspec.add_material(name="marker_dot", rgba=DOT_RGBA, emission=1.0, specular=0.0, shininess=0.0)
    for i, (b, local) in enumerate(zip(markers.body, markers.local)):
        mjspec.body(body.body_names[int(b)]).add_site(
            name=f"marker{i}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[DOT_RADIUS, 0.0, 0.0], pos=local,
            group=DOT_GROUP, material="marker_dot", rgba=DOT_RGBA)
