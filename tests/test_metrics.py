"""Metrics against hand computations and MuJoCo's own kinematics."""

import mujoco
import numpy as np
import pytest

from harness.body import SurfacePoints, body_origins
from harness.evaluation import metrics
from harness.geometry import exp, from_matrix, multiply, to_matrix, yaw
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
    assert metrics.mpjpe_pose_mm(body, est, true) == pytest.approx(0.0, abs=1e-9)


def test_mpjpe_pose_against_mujoco_positions(body, rng):
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
    assert metrics.mpjpe_pose_mm(body, est, true) == pytest.approx(expected, rel=1e-9)


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


def _camera(elevation_deg: float, t: int) -> np.ndarray:
    """World-from-camera rotations (OpenCV axes as columns) of a camera looking along world +x, pitched down."""
    e = np.deg2rad(elevation_deg)
    fwd = np.array([np.cos(e), 0.0, -np.sin(e)])
    right = np.array([0.0, -1.0, 0.0])
    down = np.cross(fwd, right)
    return np.repeat(np.stack([right, down, fwd], axis=1)[None], t, axis=0)


def test_a_body_turned_by_half_a_turn_is_right_pose_only_and_wrong_in_the_camera(body, rng):
    t = 3
    cam = _camera(20.0, t)
    angles = body.random_angles(rng, t, scale=0.3)
    world_quat = exp(rng.normal(scale=0.1, size=(t, 3)))                # nearly upright, some tilt
    true_q = from_matrix(np.swapaxes(cam, 1, 2) @ to_matrix(world_quat))
    turned_q = from_matrix(np.swapaxes(cam, 1, 2) @ to_matrix(multiply(yaw(np.full(t, np.pi)), world_quat)))
    pos = np.tile([0.2, 0.1, 4.0], (t, 1))
    true = metrics.camera_qpos(body, pos, true_q, angles)
    turned = metrics.camera_qpos(body, pos, turned_q, angles)
    assert metrics.mpjpe_pose_mm(body, turned, true) == pytest.approx(0.0, abs=1e-9)
    # Hand computation: a half turn about the vertical through the pelvis maps a joint at horizontal distance
    # r from that axis to the opposite side, 2r away; vertical offsets are unchanged.
    joints = body_origins(body, metrics.camera_qpos(body, np.zeros((t, 3)), from_matrix(
        np.swapaxes(cam, 1, 2) @ to_matrix(world_quat)), angles), frame="world")     # root at the origin
    up = cam[:, 2, :]                                                     # world z in camera coordinates
    horiz = joints - np.einsum("tjk,tk->tj", joints, up)[..., None] * up[:, None, :]
    expected = 1000.0 * np.mean(2.0 * np.linalg.norm(horiz[:, 1:], axis=-1))
    assert metrics.mpjpe_camera_mm(body, turned, true) == pytest.approx(expected, rel=1e-9)
    assert metrics.mpjpe_camera_mm(body, turned, true) > 100.0
    err = metrics.heading_tilt_errors(turned_q, true_q, cam)
    assert err["heading_err_deg"] == pytest.approx(180.0, abs=1e-6)
    assert err["tilt_err_deg"] == pytest.approx(0.0, abs=1e-6)
    # Procrustes undoes any rotation: protocol 2 sees only the (identical) pose.
    assert metrics.pa_mpjpe_mm(body, turned, true) == pytest.approx(0.0, abs=1e-6)


def test_heading_and_tilt_split_a_known_rotation():
    t = 2
    cam = _camera(35.0, t)
    true_world = exp(np.array([[0.1, -0.2, 0.7], [0.0, 0.3, -1.2]]))
    tilt = exp(np.tile([np.deg2rad(12.0), 0.0, 0.0], (t, 1)))            # about world x, after the yaw
    est_world = multiply(tilt, multiply(yaw(np.full(t, np.deg2rad(40.0))), true_world))
    to_cam = np.swapaxes(cam, 1, 2)
    out = metrics.heading_tilt_errors(from_matrix(to_cam @ to_matrix(est_world)),
                                      from_matrix(to_cam @ to_matrix(true_world)), cam)
    assert out["heading_err_deg"] == pytest.approx(40.0, abs=1e-6)
    assert out["tilt_err_deg"] == pytest.approx(12.0, abs=1e-6)


def _facing(heading_deg: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Camera-frame quaternions of an upright body whose heading (its x axis) is ``heading_deg`` about world z."""
    return from_matrix(np.swapaxes(cam, 1, 2) @ to_matrix(yaw(np.deg2rad(np.asarray(heading_deg, float)))))


def test_heading_up_to_the_twin_by_hand():
    """A level camera at the world origin's -x side looks along +x. Depth reflection through its image plane
    is world x -> -x, then the body mirror y -> -y: diag(-1, 1, 1) yaw(h) diag(1, -1, 1) = yaw(180 - h). So a
    body facing the camera (h = 180) has a twin facing away (h = 0), one seen from the side (h = 90) is its own
    twin, and at h = 135 the twin faces h = 45."""
    cam = _camera(0.0, 1)
    for true_h, est_h, direct, up_to_twin in [
            (180.0, 0.0, 180.0, 0.0),       # front view, the estimate is the twin: all of the error is the twin's
            (180.0, 170.0, 10.0, 10.0),     # front view, 10 deg off the truth (170 off the twin)
            (90.0, 120.0, 30.0, 30.0),      # side view: the twin is the truth, nothing to forgive
            (135.0, 45.0, 90.0, 0.0),       # oblique: the twin faces 45 deg
            (135.0, 60.0, 75.0, 15.0)]:
        est, true = _facing([est_h], cam), _facing([true_h], cam)
        assert metrics.heading_tilt_errors(est, true, cam)["heading_err_deg"] == pytest.approx(direct, abs=1e-6)
        assert metrics.heading_twin_error(est, true, cam)["heading_err_twin_deg"] == pytest.approx(up_to_twin,
                                                                                                  abs=1e-6)
    # Per frame: a track on the truth in frame 0 and on the twin in frame 1 (front view) is right up to the twin.
    cam2 = _camera(0.0, 2)
    est, true = _facing([180.0, 0.0], cam2), _facing([180.0, 180.0], cam2)
    assert metrics.heading_tilt_errors(est, true, cam2)["heading_err_deg"] == pytest.approx(90.0, abs=1e-6)
    assert metrics.heading_twin_error(est, true, cam2)["heading_err_twin_deg"] == pytest.approx(0.0, abs=1e-6)


def test_heading_up_to_the_twin_is_never_above_the_heading_error(rng):
    cam = _camera(25.0, 50)
    est = exp(rng.normal(scale=1.5, size=(50, 3)))
    true = exp(rng.normal(scale=1.5, size=(50, 3)))
    plain = metrics.heading_tilt_errors(est, true, cam)["heading_err_deg"]
    up_to_twin = metrics.heading_twin_error(est, true, cam)["heading_err_twin_deg"]
    assert 0.0 <= up_to_twin < plain
    assert metrics.heading_twin_error(true, true, cam)["heading_err_twin_deg"] == pytest.approx(0.0, abs=1e-6)


def test_camera_frame_mpjpe_ignores_translation_and_counts_rotation(body, rng):
    true = _walkish(body, rng)
    est = true.copy()
    est[:, :3] += [0.5, -0.3, 1.0]
    assert metrics.mpjpe_camera_mm(body, est, true) == pytest.approx(0.0, abs=1e-9)
    est[:, 3:7] = multiply(exp(np.tile([0.0, 0.0, 0.2], (len(est), 1))), true[:, 3:7])
    assert metrics.mpjpe_camera_mm(body, est, true) > 10.0
    # 17 joints: the mean over 17 with the root at zero error, against a direct computation.
    idx = metrics.h36m_joints(body)
    assert len(idx) == 17 and idx[0] == 0
    a = body_origins(body, est, "world")
    b = body_origins(body, true, "world")
    a, b = a - a[:, :1], b - b[:, :1]
    expected = 1000.0 * np.mean(np.linalg.norm(a[:, idx] - b[:, idx], axis=-1))
    assert metrics.mpjpe_camera_mm(body, est, true, idx) == pytest.approx(expected, rel=1e-12)


def test_procrustes_alignment_against_a_numerical_optimum(rng):
    from scipy.optimize import minimize

    true = rng.normal(size=(1, 17, 3))
    # A known similarity is undone exactly.
    rot = to_matrix(exp(np.array([0.3, -1.0, 2.0])))
    moved = 1.7 * true @ rot + np.array([1.0, -2.0, 0.5])
    assert np.allclose(metrics.procrustes_align(moved, true), true, atol=1e-10)
    # A noisy estimate: the closed form reaches the least-squares optimum over rotation, scale and translation.
    est = moved + rng.normal(scale=0.2, size=moved.shape)
    closed = np.sum((metrics.procrustes_align(est, true) - true) ** 2)

    def cost(x):
        return np.sum((np.exp(x[0]) * est[0] @ to_matrix(exp(x[1:4])) + x[4:] - true[0]) ** 2)

    best = min((minimize(cost, np.concatenate([[0.0], rng.normal(size=3), np.zeros(3)]), method="BFGS")
                for _ in range(8)), key=lambda r: r.fun)
    assert closed == pytest.approx(best.fun, rel=1e-6)


def test_log_p_true_is_the_log_posterior_clipped():
    post = np.array([[0.5, 0.5, 0.0], [0.7, 0.3, 0.0]])
    assert metrics.log_p_true(post, ["a", "b", "c"], "b") == pytest.approx(np.log(0.3))
    assert metrics.log_p_true(post, ["a", "b", "c"], "c") == pytest.approx(np.log(metrics.LOG_P_FLOOR))


def test_heading_error_curve_reads_the_yaw_error_at_ten_instants():
    """A heading error growing 0, 2, 4 ... 38 deg over 20 frames: the curve holds it at frames round(k 19/9)."""
    t = 20
    cam = _camera(20.0, t)
    err = 2.0 * np.arange(t)
    curve = metrics.heading_error_curve(_facing(30.0 + err, cam), _facing(np.full(t, 30.0), cam), cam, 10)
    frames = np.round(np.linspace(0, t - 1, 10)).astype(int)
    np.testing.assert_allclose(curve, err[frames], atol=1e-6)


def test_joint_errors_from_joints_computed_once_are_the_single_metrics(body, rng):
    """``joint_errors_mm`` (the evaluation's columns from one forward kinematics of each configuration) gives
    the numbers of the single metric functions, each of which runs its own; a scaled subject as the truth."""
    subject = body.scaled(np.full(body.model.nbody, 1.07))
    true = body.qpos(body.random_angles(rng, 4, scale=0.4), base_pos=np.array([[0.2, -0.1, 4.0]] * 4),
                     base_quat=np.array([[0.9, 0.1, 0.4, 0.1]] * 4) / np.linalg.norm([0.9, 0.1, 0.4, 0.1]))
    est = true.copy()
    est[:, 7:] += rng.normal(0, 0.2, est[:, 7:].shape)
    est[:, :3] += rng.normal(0, 0.1, (4, 3))
    h36m = metrics.h36m_joints(body)
    got = metrics.joint_errors_mm(body_origins(body, est, frame="world"), body_origins(subject, true, frame="world"),
                                  body_origins(body, est, frame="base"), body_origins(subject, true, frame="base"),
                                  h36m)
    want = {"mpjpe_pose_mm": metrics.mpjpe_pose_mm(body, est, true, subject),
            "mpjpe_cam_mm": metrics.mpjpe_camera_mm(body, est, true, true_body=subject),
            "mpjpe_cam17_mm": metrics.mpjpe_camera_mm(body, est, true, h36m, true_body=subject),
            "pa_mpjpe_mm": metrics.pa_mpjpe_mm(body, est, true, true_body=subject),
            "pa_mpjpe17_mm": metrics.pa_mpjpe_mm(body, est, true, h36m, true_body=subject),
            "mpjpe_abs_mm": metrics.mpjpe_absolute_mm(body, est, true, subject)}
    assert got == want
    assert all(v > 1.0 for v in got.values())
