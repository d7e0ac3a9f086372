"""Which markers the camera sees, and why the others are hidden.

A marker is visible at frame ``t`` when it is in front of the camera (``Z > NEAR``), projects inside the
image, its outward surface normal faces the camera (``n . (p - c) <= 0``, ``c`` the camera centre), and the
first geom that the ray from the camera centre towards it meets (``mujoco.mj_multiRay``, one batch per
frame, body and occluder geom groups only: the floor and the marker dots are ignored) is not nearer than
the marker itself minus ``RAY_TOLERANCE``. A blocked marker is hidden by the body itself when the first hit
belongs to the humanoid, and by an obstacle when it belongs to the world body; an unblocked marker that
faces away is hidden by the body itself.

Why the facing test: a marker lies on the surface of its own convex geom, so a ray to a back-facing marker
always crosses that geom first, but near the outline the crossing is shorter than ``RAY_TOLERANCE`` (a
marker 1 degree past the silhouette of a 5 cm limb has a 1.7 mm chord) and the ray test alone would call
it visible. The facing test is exact there, and the ray keeps deciding everything else.
"""

from __future__ import annotations

import mujoco
import numpy as np

from harness.body.surface import geom_sdf
from harness.pinhole import Intrinsics, in_image, project
from harness.scene.camera import CameraTrajectory
from harness.scene.model import SceneModel
from harness.scene.occluders import OCCLUDER_GROUP
from harness.scene.spec import SceneError

VISIBLE, OUTSIDE, SELF, OBSTACLE = 0, 1, 2, 3
NEAR = 0.05              # m: points closer to the image plane than this are not imaged
RAY_TOLERANCE = 2e-3     # m: a hit this close to the marker's own distance is the marker's surface
BODY_GROUP = 0
_RAY_GROUPS = np.zeros(6, dtype=np.uint8)
_RAY_GROUPS[[BODY_GROUP, OCCLUDER_GROUP]] = 1


def in_view(intr: Intrinsics, points_cam: np.ndarray) -> np.ndarray:
    """In front of the camera and inside the image: ``(..., 3)`` camera-frame points -> ``(...)`` bool."""
    z = points_cam[..., 2]
    front = z > NEAR
    safe = np.where(front[..., None], points_cam, np.array([0.0, 0.0, 1.0]))
    return front & in_image(intr, project(intr, safe))


def _camera_inside_body(scene: SceneModel, camera_pos: np.ndarray) -> int:
    """Geom id of a humanoid geom that contains ``camera_pos``, or -1. Only the geoms whose bounding sphere
    (MuJoCo's ``geom_rbound``) holds the camera are tested: a camera metres away skips every signed distance,
    which took 40% of a run's simulation."""
    m, d = scene.model, scene.data
    geoms = np.asarray(scene.body_geoms)
    near = np.linalg.norm(camera_pos - d.geom_xpos[geoms], axis=1) <= m.geom_rbound[geoms]
    for g in geoms[near]:
        local = (camera_pos - d.geom_xpos[g]) @ d.geom_xmat[g].reshape(3, 3)
        if geom_sdf(int(m.geom_type[g]), m.geom_size[g], local[None])[0] <= 0.0:
            return int(g)
    return -1


def marker_normals(scene: SceneModel, qpos: np.ndarray, normal_local: np.ndarray) -> np.ndarray:
    """Outward unit normals of the markers in the world frame, ``(T, N, 3)``.

    qpos: ``(T, 57)``. normal_local: ``(N, 3)`` normals in the frames of the markers' bodies.
    """
    bodies = scene.model.site_bodyid[scene.site_ids]
    out = np.empty((len(qpos), len(bodies), 3))
    for t in range(len(qpos)):
        scene.pose(qpos[t])
        rot = scene.data.xmat[bodies].reshape(-1, 3, 3)
        out[t] = np.einsum("nij,nj->ni", rot, normal_local)
    return out


def facing_away(traj: CameraTrajectory, marker_world: np.ndarray, normal_world: np.ndarray) -> np.ndarray:
    """``(T, N)`` bool: the outward normal points away from the camera, ``n . (p - c) > 0``."""
    return np.einsum("tni,tni->tn", normal_world, marker_world - traj.pos[:, None, :]) > 0.0


def classify(scene: SceneModel, qpos: np.ndarray, traj: CameraTrajectory, marker_world: np.ndarray,
             normal_world: np.ndarray) -> np.ndarray:
    """Visibility cause per marker and frame, ``(T, N)`` int8: VISIBLE, OUTSIDE, SELF or OBSTACLE.

    qpos: ``(T, 57)``. marker_world: ``(T, N, 3)`` marker positions (m). normal_world: ``(T, N, 3)`` their
    outward unit normals (``marker_normals``). Raises ``SceneError`` if the camera is inside the subject's
    body at some frame.
    """
    m, d = scene.model, scene.data
    view = in_view(traj.intrinsics, traj.to_camera(marker_world))
    cause = np.where(view, VISIBLE, OUTSIDE).astype(np.int8)
    away = facing_away(traj, marker_world, normal_world)
    for t in range(len(qpos)):
        scene.pose(qpos[t])
        inside = _camera_inside_body(scene, traj.pos[t])
        if inside >= 0:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, inside)
            raise SceneError(f"camera.distance: the camera at frame {t} is inside the subject's {name!r} geom")
        idx = np.flatnonzero(view[t])
        if len(idx) == 0:
            continue
        vec = marker_world[t, idx] - traj.pos[t]
        dist = np.linalg.norm(vec, axis=1)
        unit = np.ascontiguousarray((vec / dist[:, None]).ravel())
        geomid = np.empty(len(idx), dtype=np.int32)
        hit = np.empty(len(idx))
        mujoco.mj_multiRay(m, d, traj.pos[t].astype(float), unit, _RAY_GROUPS, 1, -1, geomid, hit, None,
                           len(idx), float(dist.max() + 1.0))
        blocked = (geomid >= 0) & (hit >= 0.0) & (hit < dist - RAY_TOLERANCE)
        by_world = m.geom_bodyid[np.maximum(geomid, 0)] == 0
        cause[t, idx] = np.where(blocked, np.where(by_world, OBSTACLE, SELF),
                                 np.where(away[t, idx], SELF, VISIBLE))
    return cause


def occlusion_fractions(cause: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the fractions of in-view markers hidden by the body and by obstacles: two ``(T,)``."""
    n_view = np.maximum((cause != OUTSIDE).sum(axis=1), 1)
    return (cause == SELF).sum(axis=1) / n_view, (cause == OBSTACLE).sum(axis=1) / n_view
