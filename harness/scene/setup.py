"""Everything about a scene that is fixed once the spec and the motion are known: the observed subject and
its motion, markers, camera trajectory, obstacles, the compiled scene and every marker's visibility. Shared by
the geometric and rendered observations and by the videos."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.body import BodyModel, SurfacePoints, forward_points
from harness.motion.motion import Motion
from harness.pinhole import project
from harness.scene.camera import CameraTrajectory, camera_trajectory
from harness.scene.markers import sample_markers
from harness.scene.model import SceneModel
from harness.scene.occluders import Obstacle, build_occluders, check_camera_outside, start_pose
from harness.scene.spec import SceneSpec
from harness.scene.subject import observed_motion, subject_body
from harness.scene.visibility import classify, in_view, marker_normals


@dataclass
class SceneSetup:
    """Everything that is fixed once the spec and motion are known (reused by rendering and videos).

    body: the observed subject (the nominal body unless ``spec.subject`` scales it). motion: the motion as
    that subject performs it (``harness.scene.subject.observed_motion``): the ground truth's configurations.
    """

    body: BodyModel
    motion: Motion
    markers: SurfacePoints
    camera: CameraTrajectory
    occluders: list[Obstacle]
    scene: SceneModel
    marker_world: np.ndarray      # (T, N, 3) m
    marker_cam: np.ndarray        # (T, N, 3) m, OpenCV camera frame
    pixels: np.ndarray            # (T, N, 2) px, NaN where behind the camera
    visibility: np.ndarray        # (T, N) int8 cause
    marker_normal: np.ndarray     # (T, N, 3) outward unit normals, world


def build_setup(motion: Motion, spec: SceneSpec, body: BodyModel | None = None) -> SceneSetup:
    """The observed subject, its markers (sampled on its own surface), the camera, the obstacles (calibrated
    presets or placed by hand), the compiled scene and the visibility of every marker.

    motion: a performance by the nominal ``body`` (default: the model file); the subject of ``spec.subject``
    plays it.
    """
    nominal = body if body is not None else BodyModel.load()
    subject = subject_body(nominal, spec.subject)
    motion = observed_motion(motion, nominal, subject, spec.subject.scale)
    markers = sample_markers(subject, spec.markers)
    traj = camera_trajectory(motion, spec.camera)
    world = forward_points(subject, motion.qpos, markers.body, markers.local)
    cam = traj.to_camera(world)
    view = in_view(traj.intrinsics, cam)
    obstacles = build_occluders(spec.occluders, traj, world, view, start_pose(motion.base_pos, motion.base_quat))
    check_camera_outside(obstacles, traj.pos,
                         "occluders.geoms" if spec.occluders.geoms else f"occluders.preset={spec.occluders.preset!r}")
    scene = SceneModel(subject, markers, obstacles, spec.camera.fovy, spec.camera.width, spec.camera.height,
                       textured=spec.observation.mode == "video")
    normals = marker_normals(scene, motion.qpos, markers.normal)
    cause = classify(scene, motion.qpos, traj, world, normals)
    front = cam[..., 2] > 0
    pixels = np.where(front[..., None], project(traj.intrinsics, np.where(front[..., None], cam, 1.0)), np.nan)
    return SceneSetup(subject, motion, markers, traj, obstacles, scene, world, cam, pixels, cause, normals)
