"""The compiled scene: the humanoid with marker sites, the occluder geoms and the scene camera (MjSpec).

One ``SceneModel`` is built per simulation; it holds one ``MjData`` and is posed frame by frame.
"""

from __future__ import annotations

import mujoco
import numpy as np

from harness.body import BodyModel, SurfacePoints
from harness.scene.markers import BODY_RGBA, add_marker_sites
from harness.scene.occluders import Obstacle, add_occluder_geoms
from harness.scene.texture import dress

CAMERA_NAME = "scene"
MAX_RENDER_SCALE = 4


class SceneModel:
    """Humanoid + markers (sites) + occluders (world geoms) + a camera that is moved every frame; the humanoid
    darkened (so that rendered marker dots stand out) or, ``textured``, dressed in cloth.

    model/data: the compiled MuJoCo model and its data. camera_id: id of the scene camera.
    site_ids: ``(N,)`` site id of marker ``i``. obstacle_geoms: ``(K,)`` geom ids of the occluders.
    """

    def __init__(self, body: BodyModel, markers: SurfacePoints, boxes: list[Obstacle], fovy: float,
                 width: int, height: int, textured: bool = False):
        spec = body.mjspec()
        if textured:
            dress(spec)           # cloth, for the video pipeline's corners (harness.scene.texture)
        else:
            for mat in spec.materials:
                if mat.name == "skin":
                    mat.rgba = BODY_RGBA
        add_marker_sites(spec, body, markers)
        add_occluder_geoms(spec, boxes)
        spec.worldbody.add_camera(name=CAMERA_NAME, fovy=float(fovy), pos=[0.0, 0.0, 0.0])
        # Room for supersampled renders (the depth-buffer check renders at up to MAX_RENDER_SCALE x).
        spec.visual.global_.offwidth = max(MAX_RENDER_SCALE * int(width), spec.visual.global_.offwidth)
        spec.visual.global_.offheight = max(MAX_RENDER_SCALE * int(height), spec.visual.global_.offheight)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.camera_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
        self.site_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"marker{i}")
                                  for i in range(len(markers))], dtype=int)
        self.obstacle_geoms = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"occluder{k}")
                                        for k in range(len(boxes))], dtype=int)
        self.body_geoms = np.flatnonzero(m.geom_bodyid > 0)

    def pose(self, qpos: np.ndarray, camera_pos: np.ndarray | None = None,
             camera_quat_mujoco: np.ndarray | None = None) -> None:
        """Place the humanoid at ``qpos (57,)`` and, if given, the camera (world position, MuJoCo wxyz)."""
        m, d = self.model, self.data
        d.qpos[:] = qpos
        if camera_pos is not None:
            m.cam_pos[self.camera_id] = camera_pos
            m.cam_quat[self.camera_id] = camera_quat_mujoco
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
