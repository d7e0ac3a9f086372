"""Metrics against hand computations and MuJoCo's own kinematics."""

import mujoco
import numpy as np
import pytest

from harness.body import SurfacePoints, body_origins
from harness.evaluation import metrics
from harness.geometry import exp, to_matrix
from harness.pinhole import Intrinsics


def _walkish(body, rng, t=4):
    angles = body.random_angles(rng, t, scale=0.3)
    quat = exp(rng.normal(scale=0.3, size=(t, 3)))
    pos = np.array([0.1, -0.2, 4.0]) + rng.normal(scale=0.05, size=(t, 3))
    return metrics.camera_qpos(body, pos, quat, angles)


def test_time_to_correct_from_a_hand_made_posterior():
    classes = ["walk", "run", "jump"]
    # argmax per frame: run, walk, run, walk, walk, walk -> correct (walk) from frame 3 on.
    post = np.array([[.2, .7, .1], [.5, .4, .1], [.3, .6, .1], [.6, .3, .1], [.8, .1, .1], [.9, .05, .05]])
    out = metrics.recognition(post, classes, "walk", fps=10.0)
    assert out == {"class_pred": "walk", "correct": 1, "frame_accuracy": pytest.approx(4 / 6),
                   "time_to_correct_s": pytest.approx(0.3)}
    wrong_end = metrics.recognition(post[[3, 0]], classes, "walk", fps=10.0)
    assert wrong_end["correct"] == 0 and wrong_end["class_pred"] == "run"
    assert np.isnan(wrong_end["time_to_correct_s"]) and wrong_end["frame_accuracy"] == 0.5
    assert metrics.recognition(post[3:], classes, "walk", fps=30.0)["time_to_correct_s"] == 0.0
    with pytest.raises(ValueError, match="not one of the classes"):
        metrics.recognition(post, classes, "kick", fps=10.0)


def test_angle_rms_is_the_rms_of_known_differences_and_wraps():
    true = np.zeros((2, 50))
    est = true.copy()
    est[0, 0], est[1, 7] = np.deg2rad(3.0), np.deg2rad(-4.0)
    assert metrics.angle_rms_deg(est, true) == pytest.approx(np.sqrt((9 + 16) / 100))
    est2 = true + np.deg2rad(359.0)          # one degree the short way round
    assert metrics.angle_rms_deg(est2, true) == pytest.approx(1.0)


def test_mpjpe_with_a_known_offset(body, rng):
    true = _walkish(body, rng)
    offset = np.array([0.03, -0.04, 0.12])    # |offset| = 0.13 m
    est = true.copy()
    est[:, :3] += offset
    assert metrics.mpjpe_absolute_mm(body, est, true) == pytest.approx(130.0, abs=1e-9)
    # A base offset (and a different base rotation) is invisible root-relative.
    est[:, 3:7] = exp(rng.normal(size=(len(est), 3)))
    assert metrics.mpjpe_relative_mm(body, est, true) == pytest.approx(0.0, abs=1e-9)


def test_mpjpe_relative_against_mujoco_positions(body, rng):
    true = body.zero_qpos()[None]
    est = true.copy()
    knee = body.angle_qpos_index[body.joint_names.index(next(n for n in body.joint_names if "tibia" in n))]
    est[0, knee] += 0.5
    d = mujoco.MjData(body.model)
    pos = []
    for q in (est[0], true[0]):
        d.qpos[:] = q
        mujoco.mj_kinematics(body.model, d)
        pos.append(d.xpos[2:].copy())   # every body but world and root; the base stays at its zero pose
    expected = 1000.0 * np.mean(np.linalg.norm(pos[0] - pos[1], axis=1))
    assert expected > 1.0
    assert metrics.mpjpe_relative_mm(body, est, true) == pytest.approx(expected, rel=1e-9)


def test_base_errors_of_a_known_rotation_and_translation():
    true_q = np.tile([1.0, 0, 0, 0], (3, 1))
    est_q = exp(np.tile([0.0, 0.0, np.deg2rad(30.0)], (3, 1)))
    true_p = np.zeros((3, 3))
    est_p = np.tile([0.3, 0.0, -0.4], (3, 1))
    out = metrics.base_errors(est_p, est_q, true_p, true_q)
    assert out["base_pos_err_m"] == pytest.approx(0.5)
    assert out["base_depth_err_m"] == pytest.approx(0.4)
    assert out["base_rot_err_deg"] == pytest.approx(30.0)


def test_reprojection_error_of_a_shifted_observation(body, rng):
    qpos = _walkish(body, rng, t=3)
    intr = Intrinsics.from_fov(45.0, 640, 480)
    bodies = np.array([body.root_body, body.root_body])
    local = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    markers = SurfacePoints(bodies, np.zeros(2, int), local, np.tile([1.0, 0, 0], (2, 1)))
    # Independent projection: the root body's world pose is the base pose itself.
    frame, marker = np.array([0, 1, 2, 2]), np.array([0, 1, 0, 1])
    rot = to_matrix(qpos[frame, 3:7])
    cam = qpos[frame, :3] + np.einsum("nij,nj->ni", rot, local[marker])
    uv = np.stack([intr.fx * cam[:, 0] / cam[:, 2] + intr.cx, intr.fy * cam[:, 1] / cam[:, 2] + intr.cy], 1)
    shift = np.array([[3.0, 4.0], [0.0, 0.0], [-6.0, 8.0], [1.0, 0.0]])   # distances 5, 0, 10, 1
    err = metrics.reprojection_px(body, qpos, markers, intr, frame, marker, uv + shift)
    assert err == pytest.approx(4.0, abs=1e-9)
    assert np.isnan(metrics.reprojection_px(body, qpos, markers, intr, frame[:0], marker[:0], uv[:0]))
    assert np.allclose(body_origins(body, qpos)[:, 0], qpos[:, :3])
