"""Small, self-contained inputs for the engine's tests: three simple primitives and a facing-only camera.

Independent of the scene package on purpose: the engine is tested on its own contract (observations in,
estimates out), with a projection written here from the body's FK and the pinhole model.
"""

import numpy as np

from harness import geometry
from harness.body import forward_points, sample_surface
from harness.engine.particle_filter import camera_pitch, upright_orientations
from harness.motion import Motion
from harness.observation import Observation
from harness.pinhole import Intrinsics, project

CLASSES = ("march", "wave", "squat")


def synthetic_demos(body, label, n, rng, fps=30.0, seconds=2.0):
    """``n`` demonstrations of a simple primitive with random tempo, amplitude and noise."""
    out = []
    for i in range(n):
        T = int(seconds * fps)
        t = np.arange(T) / fps
        tempo = rng.uniform(0.85, 1.15)
        amp = rng.uniform(0.85, 1.15)
        phase = 2 * np.pi * tempo * t
        a = np.zeros((T, 50))
        pos = np.zeros((T, 3))
        pos[:, 2] = 0.95
        if label == "march":
            swing = 0.5 * amp * np.sin(phase)
            a[:, body.angle_index("lfemur_y")] = -0.3 + swing
            a[:, body.angle_index("rfemur_y")] = -0.3 - swing
            a[:, body.angle_index("ltibia_y")] = 0.5 + 0.4 * amp * np.maximum(np.sin(phase), 0)
            a[:, body.angle_index("rtibia_y")] = 0.5 + 0.4 * amp * np.maximum(-np.sin(phase), 0)
            a[:, body.angle_index("lhumerus_y")] = 0.4 * amp * np.sin(phase)
            a[:, body.angle_index("rhumerus_y")] = -0.4 * amp * np.sin(phase)
            pos[:, 0] = 0.8 * tempo * t
        elif label == "wave":
            a[:, body.angle_index("rhumerus_x")] = -2.2 * amp
            a[:, body.angle_index("rradius_y")] = -0.8 + 0.5 * amp * np.sin(2 * phase)
            a[:, body.angle_index("lowerneck_z")] = 0.2 * np.sin(phase)
        elif label == "squat":
            depth = amp * 0.5 * (1 - np.cos(phase))
            a[:, body.angle_index("lfemur_y")] = -1.2 * depth
            a[:, body.angle_index("rfemur_y")] = -1.2 * depth
            a[:, body.angle_index("ltibia_y")] = 1.8 * depth
            a[:, body.angle_index("rtibia_y")] = 1.8 * depth
            a[:, body.angle_index("lhumerus_y")] = -1.2 * depth
            a[:, body.angle_index("rhumerus_y")] = -1.2 * depth
            pos[:, 2] = 0.95 - 0.35 * depth
        else:
            raise ValueError(label)
        a += np.cumsum(rng.normal(0, 0.004, (T, 50)), axis=0)
        a = np.clip(a, body.lower, body.upper)
        quat = np.tile([1.0, 0, 0, 0], (T, 1))
        out.append(Motion(np.concatenate([pos, quat, a], axis=1), fps, label, demo=str(i), source="test"))
    return out


def synthetic_observation(body, motion, rng, n_markers=100, noise_px=1.0, distance=4.0, heading=None,
                          elevation_deg=0.0):
    """Flows of facing markers seen by a camera ``distance`` m from a point 1 m above the subject's mean
    position on the floor, looking at it from ``elevation_deg`` above the horizontal (level by default).

    Returns (Observation, base position (T, 3) and quaternion (T, 4) in the camera frame)."""
    intr = Intrinsics.from_fov(45.0, 640, 480)
    heading = rng.uniform(-np.pi, np.pi) if heading is None else heading
    markers = sample_surface(body, n_markers, rng)
    # Camera frame from a body-relative placement: the body's world pose composed with a fixed camera pose.
    cam_from_world = geometry.to_matrix(upright_orientations(np.array([heading]),
                                                            camera_pitch(np.deg2rad(elevation_deg))))[0]
    centre = motion.base_pos.mean(axis=0) * np.array([1, 1, 0]) + np.array([0, 0, 1.0])
    world = forward_points(body, motion.qpos, markers.body, markers.local)
    normals = forward_points(body, motion.qpos, markers.body, markers.local + markers.normal) - world
    X = (world - centre) @ cam_from_world.T + np.array([0, 0, distance])
    n_cam = normals @ cam_from_world.T
    visible = (np.einsum("tpi,tpi->tp", n_cam, X) < 0) & (X[..., 2] > 0.1)
    pix = project(intr, X) + rng.normal(0, noise_px, X.shape[:2] + (2,))
    from harness.pinhole import in_image
    visible &= in_image(intr, pix)
    flows = [np.empty((0, 4))]
    for t in range(1, len(X)):
        both = visible[t] & visible[t - 1]
        f = np.concatenate([pix[t, both], (pix[t, both] - pix[t - 1, both]) * motion.fps], axis=1)
        flows.append(f[rng.permutation(len(f))])
    base_pos = (motion.base_pos - centre) @ cam_from_world.T + np.array([0, 0, distance])
    base_quat = geometry.multiply(geometry.from_matrix(cam_from_world), motion.base_quat)
    return Observation(motion.fps, intr, flows), base_pos, base_quat
