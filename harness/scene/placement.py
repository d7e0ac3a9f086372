"""Where a camera would stand, checked before anything runs (the parts that do not depend on the motion).

The camera's position relative to the look-at point is fixed by its spec (distance, azimuth, elevation,
look-at height). Taking the subject standing in the zero pose at the look-at point, facing its initial
heading, and the obstacles given by hand in its start frame with the start at the look-at point (exact for
primitives performed in place; for travelling ones the scene checks again with the real motion), a camera
is refused when it is at or below the floor, inside the standing subject, or inside an obstacle, and an
obstacle when it holds a part of the standing subject (a box around the subject hides everything and gives a
run with nothing seen). Presets are placed between camera and subject by construction and are checked by the
scene.
"""

from __future__ import annotations

from functools import lru_cache

import mujoco
import numpy as np

from harness.body import nominal_body
from harness.body.surface import geom_sdf
from harness.scene.occluders import custom_obstacles
from harness.scene.spec import CameraSpec, OccluderSpec, SceneError, SubjectSpec


@lru_cache(maxsize=1)
def _standing_geoms() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """The nominal body's geoms in the zero pose, base at the origin's xy: types, sizes, centres, rotations,
    names."""
    body = nominal_body()
    q = body.zero_qpos()
    q[:2] = 0.0
    d = body.data
    d.qpos[:] = q
    mujoco.mj_kinematics(body.model, d)
    g = body.body_geoms
    names = tuple(mujoco.mj_id2name(body.model, mujoco.mjtObj.mjOBJ_GEOM, int(i)) for i in g)
    return (body.model.geom_type[g].copy(), body.model.geom_size[g].copy(), d.geom_xpos[g].copy(),
            d.geom_xmat[g].reshape(-1, 3, 3).copy(), names)


def camera_offsets(camera: CameraSpec, azimuths_deg: np.ndarray) -> np.ndarray:
    """Camera centres ``(A, 3)`` relative to the subject's start on the floor (x along its initial heading),
    with the look-at point above the start, for each azimuth (degrees)."""
    az = np.deg2rad(np.asarray(azimuths_deg, dtype=float))
    el = np.deg2rad(camera.elevation)
    return np.stack([camera.distance * np.cos(el) * np.cos(az), camera.distance * np.cos(el) * np.sin(az),
                     np.full(len(az), camera.look_at_height + camera.distance * np.sin(el))], axis=1)


def check_camera_placement(camera: CameraSpec, occluders: OccluderSpec, subject: SubjectSpec,
                           azimuths_deg: np.ndarray) -> None:
    """Raise ``SceneError`` (key, value, why) if the camera, at any of ``azimuths_deg``, is at or below the
    floor, inside the standing subject (scaled by ``subject.scale``) or inside an obstacle of ``occluders.geoms``."""
    pos = camera_offsets(camera, azimuths_deg)
    low = np.flatnonzero(pos[:, 2] <= 0.0)
    if len(low):
        raise SceneError("camera below the floor", "camera.elevation", camera.elevation,
                         f"the camera is at or below the floor (z={pos[low[0], 2]:.2f} m with look_at_height "
                         f"{camera.look_at_height:g} m)")
    types, sizes, centres, rots, names = _standing_geoms()
    nominal = pos / subject.scale                   # a uniformly scaled subject is the nominal one, scaled
    for k in range(len(types)):
        local = (nominal - centres[k]) @ rots[k]
        inside = geom_sdf(int(types[k]), sizes[k], local) <= 0.0
        if inside.any():
            a = float(np.asarray(azimuths_deg)[np.argmax(inside)])
            raise SceneError("camera inside the subject", "camera.distance", camera.distance,
                             f"the camera (azimuth {a:g} deg) is inside the standing subject's {names[k]!r} geom")
    for k, ob in enumerate(custom_obstacles(occluders.geoms, np.zeros(3), 0.0)):
        inside = geom_sdf(ob.geom_type, ob.half, ob.to_local(pos)) <= 0.0
        if inside.any():
            a = float(np.asarray(azimuths_deg)[np.argmax(inside)])
            raise SceneError("camera inside an obstacle", f"occluders.geoms[{k}]", occluders.geoms[k],
                             f"the camera (azimuth {a:g} deg, at {np.round(pos[np.argmax(inside)], 2).tolist()} m "
                             f"from the subject's start) is inside this obstacle")


def check_obstacles_clear(occluders: OccluderSpec, subject: SubjectSpec) -> None:
    """Raise ``SceneError`` if an obstacle of ``occluders.geoms`` holds the centre of one of the standing
    subject's geoms (scaled by ``subject.scale``, at the start): the body would stand inside it."""
    if not occluders.geoms:
        return
    types, sizes, centres, rots, names = _standing_geoms()
    body = centres * subject.scale
    for k, ob in enumerate(custom_obstacles(occluders.geoms, np.zeros(3), 0.0)):
        inside = geom_sdf(ob.geom_type, ob.half, ob.to_local(body)) <= 0.0
        if inside.any():
            raise SceneError("obstacle around the subject", f"occluders.geoms[{k}]", occluders.geoms[k],
                             f"this obstacle holds the standing subject's {names[int(np.argmax(inside))]!r} geom "
                             f"(the body would stand inside it and nothing would be seen)")
