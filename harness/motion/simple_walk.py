"""A simple synthetic walk (sinusoidal legs and arms, feet on the floor) for the scene's tests and acceptance
checks: shorter and simpler than a procedural demonstration, so that rendering checks are quick and repeatable.

The base advances along +x at ``speed`` m/s facing +x; hips, knees, ankles, shoulders and elbows swing with
sinusoids inside their joint limits; the base height is set each frame so that the lowest point of the
body touches the floor.
"""

from __future__ import annotations

import numpy as np

from harness.body import BodyModel, geom_z_range
from harness.motion.motion import Motion


def walk_motion(body: BodyModel, n_frames: int = 60, fps: float = 30.0, speed: float = 1.2,
                stride_hz: float = 0.9, heading: float = 0.0) -> Motion:
    """``n_frames`` of walking at ``speed`` m/s, facing ``heading`` (rad about z) from the origin."""
    t = np.arange(n_frames) / fps
    phase = 2.0 * np.pi * stride_hz * t
    angles = np.zeros((n_frames, 50))
    deg = np.deg2rad
    for side, sign in (("l", 1.0), ("r", -1.0)):
        s = np.sin(phase) * sign
        angles[:, body.angle_index(f"{side}femur_y")] = deg(-22.0) * s - deg(5.0)          # hip flexion < 0
        angles[:, body.angle_index(f"{side}tibia_y")] = deg(35.0) * np.clip(np.sin(phase * sign + 0.6), 0, None) \
            + deg(5.0)
        angles[:, body.angle_index(f"{side}foot_y")] = deg(8.0) * np.cos(phase) * sign
        angles[:, body.angle_index(f"{side}humerus_y")] = deg(20.0) * s              # arms swing against legs
        angles[:, body.angle_index(f"{side}radius_y")] = deg(-25.0) - deg(10.0) * s
    angles[:, body.angle_index("lhumerus_x")] = deg(8.0)
    angles[:, body.angle_index("rhumerus_x")] = deg(-8.0)
    angles = body.clip_angles(angles)
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    quat = np.array([np.cos(0.5 * heading), 0.0, 0.0, np.sin(0.5 * heading)])
    qpos = body.qpos(angles, base_pos=np.outer(speed * t, direction) + [0.0, 0.0, 0.95], base_quat=quat)
    lowest = geom_z_range(body, qpos)[:, :, 0].min(axis=1)
    qpos[:, 2] -= lowest
    return Motion(qpos, fps, "walk", source="synthetic:simple_walk")
