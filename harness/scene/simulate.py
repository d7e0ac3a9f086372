"""From a played-back motion to what one camera observes: unlabeled 2D flows, and the ground truth apart.

Flow definition (``harness.observation``): for frames ``t >= 1``, every marker visible at both ``t - 1``
and ``t`` gives a row ``(u, v, du, dv)``: its measured pixel at ``t`` and ``(p_t - p_{t-1}) * fps`` in
pixels per second. Geometric mode measures ``p_t`` as the projected marker plus Gaussian noise of
``noise_px`` drawn independently for every marker and frame (so the flow's noise is the difference of two
independent draws). Each flow is then dropped with probability ``dropout``; ``round(outliers * M)``
outlier rows are added (``M`` the visible count before dropout), uniform over the image with velocities
uniform in ``[-OUTLIER_SPEED, OUTLIER_SPEED]`` px/s per axis; rows are shuffled. Rendered mode replaces the
projected markers by dots detected in MuJoCo images and tracked with Lucas-Kanade (``harness.scene.rendered``;
no synthetic pixel noise is added there, the image processing has its own), then applies the same
dropout, outliers and shuffling. Video mode renders the subject in cloth and finds its flows with
``track-video``'s pipeline (``harness.scene.footage``: background subtraction, corners, Lucas-Kanade; no
synthetic noise, no marker ids), then the same dropout, outliers and shuffling.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness import geometry
from harness.body import BodyModel, SurfacePoints
from harness.io import save_npz_atomic
from harness.motion.motion import Motion
from harness.observation import Observation
from harness.pinhole import Intrinsics, in_image
from harness.scene.camera import camera_velocity
from harness.scene.footage import video_flows
from harness.scene.occluders import GEOM_TYPES, Obstacle
from harness.scene.rendered import rendered_flows
from harness.scene.setup import SceneSetup, build_setup
from harness.scene.spec import ObservationSpec, SceneError, SceneSpec
from harness.scene.visibility import OUTSIDE, VISIBLE, occlusion_fractions

__all__ = ["GroundTruth", "SceneSetup", "SceneWarning", "build_setup", "finish_frames", "geometric_flows",
           "simulate"]

OUTLIER_SPEED = 300.0   # px/s: bound of each outlier velocity component (10 px per frame at 30 fps)
OUTLIER_ID = -1         # the ground-truth marker id of an outlier row


class SceneWarning(UserWarning):
    """A scene that runs but observes nothing useful (for example a camera that sees no marker)."""


@dataclass
class GroundTruth:
    """What the engine must not see; ``T`` frames, ``N`` markers.

    marker_ids: per frame ``(M_t,)`` int, the marker of each flow row, -1 (``OUTLIER_ID``) for outlier rows (and,
    in rendered mode, for tracked dots that match no visible marker), -2 for video mode's features (no markers:
    ``harness.scene.footage.FEATURE_ID``). markers: the placement, in the frames of the
    observed subject's bodies. qpos: ``(T, 57)`` world, the observed subject's configurations.
    base_pos_cam: ``(T, 3)`` m and base_quat_cam: ``(T, 4)`` wxyz, the base in the camera frame (OpenCV).
    camera_pos: ``(T, 3)`` world m. camera_rot: ``(T, 3, 3)`` world-from-camera, OpenCV axes as columns.
    visibility: ``(T, N)`` int8 cause (0 visible, 1 outside view, 2 hidden by the body, 3 by an obstacle).
    self_fraction, obstacle_fraction: ``(T,)`` fractions of the in-view markers hidden by each cause.
    pixels: ``(T, N, 2)`` true projected marker pixels (NaN behind the camera). occluders: the obstacles.
    segment_scale: ``(nbody,)`` the observed subject's segment factors against the model file (ones: nominal;
    ``BodyModel.scaled`` rebuilds the subject's body from them).
    """

    marker_ids: list[np.ndarray]
    markers: SurfacePoints
    qpos: np.ndarray
    base_pos_cam: np.ndarray
    base_quat_cam: np.ndarray
    camera_pos: np.ndarray
    camera_rot: np.ndarray
    visibility: np.ndarray
    self_fraction: np.ndarray
    obstacle_fraction: np.ndarray
    pixels: np.ndarray
    occluders: list[Obstacle]
    segment_scale: np.ndarray

    def obstacle_occlusion(self) -> float:
        """Pooled fraction of in-view marker-frames hidden by obstacles."""
        n = int((self.visibility != OUTSIDE).sum())
        return float((self.visibility == 3).sum() / n) if n else 0.0

    def save(self, path: str | Path) -> None:
        """Plain ``.npz`` (no pickle); ragged ``marker_ids`` stored flat with per-frame counts."""
        kinds = list(GEOM_TYPES)
        boxes = np.array([np.concatenate([[kinds.index(b.kind)], b.centre, b.half, [b.yaw]])
                          for b in self.occluders]).reshape(-1, 8)
        save_npz_atomic(path, {
            "marker_ids": np.concatenate(self.marker_ids) if self.marker_ids else np.empty(0, int),
            "marker_counts": np.array([len(i) for i in self.marker_ids], dtype=int),
            "marker_body": self.markers.body, "marker_geom": self.markers.geom,
            "marker_local": self.markers.local, "marker_normal": self.markers.normal,
            "qpos": self.qpos, "base_pos_cam": self.base_pos_cam, "base_quat_cam": self.base_quat_cam,
            "camera_pos": self.camera_pos, "camera_rot": self.camera_rot, "visibility": self.visibility,
            "self_fraction": self.self_fraction, "obstacle_fraction": self.obstacle_fraction,
            "pixels": self.pixels, "occluders": boxes, "segment_scale": self.segment_scale,
        })

    @classmethod
    def load(cls, path: str | Path) -> "GroundTruth":
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
            bounds = np.concatenate([[0], np.cumsum(a["marker_counts"])])
            ids = [a["marker_ids"][bounds[t]:bounds[t + 1]] for t in range(len(a["marker_counts"]))]
            markers = SurfacePoints(a["marker_body"], a["marker_geom"], a["marker_local"], a["marker_normal"])
            kinds = list(GEOM_TYPES)
            boxes = [Obstacle(r[1:4], r[4:7], float(r[7]), kinds[int(r[0])]) for r in a["occluders"]]
            return cls(ids, markers, a["qpos"], a["base_pos_cam"], a["base_quat_cam"], a["camera_pos"],
                       a["camera_rot"], a["visibility"], a["self_fraction"], a["obstacle_fraction"],
                       a["pixels"], boxes, a["segment_scale"])
        except FileNotFoundError:
            raise SceneError(f"{path}: no such ground-truth file") from None
        except (KeyError, ValueError, IndexError, OSError, EOFError) as exc:
            raise SceneError(f"{path}: not a ground-truth file ({type(exc).__name__})") from None


def geometric_flows(pixels: np.ndarray, visible: np.ndarray, fps: float, noise_px: float,
                    intr: Intrinsics, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Noisy flows of markers visible in consecutive frames, unshuffled: per frame ``(rows (M, 4), ids (M,))``.

    pixels: ``(T, N, 2)`` true pixels; visible: ``(T, N)`` bool. Noise ``(T, N, 2)`` is drawn in one call
    whatever the visibility, so that the random stream does not depend on the scene. Rows whose noisy
    position leaves the image are dropped.
    """
    noise = rng.standard_normal(pixels.shape) * noise_px
    measured = pixels + noise
    out = [(np.empty((0, 4)), np.empty(0, dtype=int))]
    for t in range(1, len(pixels)):
        idx = np.flatnonzero(visible[t - 1] & visible[t])
        p0, p1 = measured[t - 1, idx], measured[t, idx]
        keep = in_image(intr, p1)
        idx, p0, p1 = idx[keep], p0[keep], p1[keep]
        out.append((np.concatenate([p1, (p1 - p0) * fps], axis=1), idx))
    return out


def finish_frames(frames: list[tuple[np.ndarray, np.ndarray]], obs: ObservationSpec, intr: Intrinsics,
                  rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Dropout, outliers and shuffling of every frame's ``(rows, ids)``; returns flows and marker ids."""
    flows, ids = [], []
    for t, (rows, idx) in enumerate(frames):
        n_visible = len(rows)
        keep = rng.random(n_visible) >= obs.dropout
        rows, idx = rows[keep], idx[keep]
        n_out = int(round(obs.outliers * n_visible)) if t > 0 else 0
        pos = rng.uniform([0.0, 0.0], [intr.width, intr.height], size=(n_out, 2))
        vel = rng.uniform(-OUTLIER_SPEED, OUTLIER_SPEED, size=(n_out, 2))
        rows = np.concatenate([rows, np.concatenate([pos, vel], axis=1)])
        idx = np.concatenate([idx, np.full(n_out, OUTLIER_ID, dtype=int)])
        order = rng.permutation(len(rows))
        flows.append(rows[order])
        ids.append(idx[order])
    return flows, ids


def simulate(motion: Motion, spec: SceneSpec, rng: np.random.Generator, body: BodyModel | None = None
             ) -> tuple[Observation, GroundTruth]:
    """What the camera of ``spec`` observes of ``motion``: the engine's input, and the ground truth apart.

    Same ``rng`` state, same spec: bit-identical output in geometric mode. A camera that sees none of the
    markers gives an empty observation and a ``SceneWarning``.
    """
    setup = build_setup(motion, spec, body)
    traj, cause = setup.camera, setup.visibility
    visible = cause == VISIBLE
    if not visible.any():
        warnings.warn(f"the camera sees none of the {len(setup.markers)} markers over {motion.n_frames} frames "
                      f"(camera {spec.camera}); the observation is empty", SceneWarning, stacklevel=2)
    motion = setup.motion
    if spec.observation.mode == "rendered":
        frames = rendered_flows(setup, motion.qpos, motion.fps)
    elif spec.observation.mode == "video":
        frames = video_flows(setup, motion.qpos, motion.fps)
    else:
        frames = geometric_flows(setup.pixels, visible, motion.fps, spec.observation.noise_px,
                                 traj.intrinsics, rng)
    flows, ids = finish_frames(frames, spec.observation, traj.intrinsics, rng)
    prior = spec.observation.camera_prior
    # World z is up and the floor is z = 0: gravity in the camera frame is R^T (0, 0, -1), the height is z.
    gravity = -traj.rot[:, 2, :] if prior in ("gravity", "floor") else None
    height = traj.pos[:, 2].copy() if prior == "floor" else None
    observation = Observation(motion.fps, traj.intrinsics, flows,
                              camera_velocity(traj, motion.fps) if traj.moving else None, gravity, height)
    rot_t = np.swapaxes(traj.rot, 1, 2)
    base_pos_cam = np.einsum("tij,tj->ti", rot_t, motion.base_pos - traj.pos)
    base_rot_cam = rot_t @ geometry.to_matrix(motion.base_quat)
    self_fraction, obstacle_fraction = occlusion_fractions(cause)
    truth = GroundTruth(ids, setup.markers, np.array(motion.qpos), base_pos_cam, geometry.from_matrix(base_rot_cam),
                        traj.pos, traj.rot, cause, self_fraction, obstacle_fraction, setup.pixels, setup.occluders,
                        setup.body.segment_scale.copy())
    return observation, truth
