"""Proto-symbol reproduction: smoothing, generation, body scale, mirror, world frame; DTW scores."""

import itertools

import numpy as np
import pytest

from harness import geometry
from harness.body import geom_z_range
from harness.body.grounding import foot_geoms
from harness.engine.database import MotionDatabase
from harness.motion.performer import CYCLIC
from harness.engine.features import motion_features
from harness.body.model import mirror_angles
from harness.engine.reproduction import (class_mean, expected_path, generate_angles, recovered_world, reproduce,
                                         smooth_states, state_path)
from harness.engine.switching import SwitchingRecognizer
from harness.evaluation.reproduction_metrics import dtw_angle_rms_deg, dtw_mpjpe_mm, dtw_path
from harness.motion.performer import demonstrations, training_set


@pytest.fixture(scope="module")
def db(body):
    return MotionDatabase(n_states=10, cyclic=CYCLIC).fit(
        training_set(("walk", "squat", "kick"), 4, seed=0, body=body))


def _filtered_path(db, motion, label):
    """The joint posteriors of the joint-space recursion over a demonstration, and the smoothed state path of
    ``label``."""
    rec = SwitchingRecognizer(db, 0.0, prune=0.0)
    joint = []
    for log_b in db.log_emissions(motion_features(motion)):
        rec.predict()
        rec.update(log_b)
        joint.append(rec.posterior)
    return state_path(db, np.array(joint), label)


def test_smoothing_from_filtered_posteriors_is_forward_backward():
    rng = np.random.default_rng(0)
    K, T = 3, 7
    A = rng.dirichlet(np.ones(K), size=K)
    pi = rng.dirichlet(np.ones(K))
    b = np.exp(rng.normal(0, 1.5, size=(T, K)))
    alpha = np.empty((T, K))
    alpha[0] = pi * b[0]
    for t in range(1, T):
        alpha[t] = (alpha[t - 1] @ A) * b[t]
    beta = np.ones((T, K))
    for t in range(T - 2, -1, -1):
        beta[t] = A @ (b[t + 1] * beta[t + 1])
    smoothed = alpha * beta / (alpha * beta).sum(axis=1, keepdims=True)
    filtered = alpha / alpha.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(smooth_states(A, filtered), smoothed, atol=1e-12)


def test_generation_is_the_weighted_least_squares_trajectory():
    rng = np.random.default_rng(1)
    K, T, fps = 4, 9, 30.0
    means = rng.normal(0, 0.5, size=(K, 106))
    covars = rng.uniform(0.01, 0.2, size=(K, 106))
    path = rng.dirichlet(np.ones(K), size=T)
    got = generate_angles(means, covars, path, fps)
    D = np.gradient(np.eye(T), 1.0 / fps, axis=0)                      # the features' own rate definition
    for j in (0, 17, 49):
        m = path @ means[:, j]
        v = path @ (covars[:, j] + means[:, j] ** 2) - m**2
        r = path @ means[:, 50 + j]
        w = path @ (covars[:, 50 + j] + means[:, 50 + j] ** 2) - r**2
        W = np.concatenate([np.eye(T) / np.sqrt(v)[:, None], D / np.sqrt(w)[:, None]])
        y = np.concatenate([m / np.sqrt(v), r / np.sqrt(w)])
        np.testing.assert_allclose(got[:, j], np.linalg.lstsq(W, y, rcond=None)[0], atol=1e-9)


def test_expected_path_visits_every_state_in_order_for_its_expected_dwell():
    A = np.diag([0.5, 0.75, 0.9, 1.0]) + np.diag([0.5, 0.25, 0.1], k=1)
    path = expected_path(A, 60)
    k = path.argmax(axis=1)
    assert path.sum(axis=1).tolist() == [1.0] * 60 and np.all(np.diff(k) >= 0) and set(k) == {0, 1, 2, 3}
    # Dwells 2, 4, 10 and (absorbing) the median 4, stretched to 60 frames: 6, 12, 30, 12.
    assert np.bincount(k).tolist() == [6, 12, 30, 12]


@pytest.mark.parametrize("scale", [0.8, 1.2])
def test_a_reproduction_in_another_body_scale_keeps_its_feet_on_the_floor(body, db, scale):
    motion = demonstrations("squat", 1, np.random.default_rng(3), subject=1001, body=body)[0]
    path = _filtered_path(db, motion, "squat")
    robot = body.scaled(np.where(np.arange(body.model.nbody) > 0, scale, 1.0))
    rep = reproduce(db, robot, "squat", path, 30.0, start_xy=np.array([1.0, 2.0]), start_heading=0.5)
    low = geom_z_range(robot, rep.qpos, foot_geoms(robot))[:, :, 0].min(axis=1)
    np.testing.assert_allclose(low, 0.0, atol=1e-9)
    # The nominal body's base heights would float the scaled body or sink it by centimetres.
    nominal = reproduce(db, body, "squat", path, 30.0)
    assert np.abs(nominal.base_pos[:, 2] - rep.base_pos[:, 2]).min() > 0.05
    assert np.allclose(rep.base_pos[0, :2], [1.0, 2.0]) and abs(geometry.heading(rep.base_quat[0]) - 0.5) < 1e-9


def test_the_mirrored_reproduction_is_the_mirror_image_of_the_reproduction(body, db):
    """Generated from the mirrored states, the angles are the mirrored angles of the plain reproduction and the
    base turns the other way (the generation is linear in the states' means)."""
    motion = demonstrations("kick", 1, np.random.default_rng(4), subject=1002, body=body)[0]
    path = _filtered_path(db, motion, "kick")
    plain = reproduce(db, body, "kick", path, 30.0)
    mirrored = reproduce(db, body, "kick", path, 30.0, mirror=True)
    np.testing.assert_allclose(mirrored.angles, np.clip(mirror_angles(plain.angles), body.lower, body.upper),
                               atol=1e-9)
    turn = lambda m: np.unwrap(geometry.heading(m.base_quat))  # noqa: E731
    np.testing.assert_allclose(turn(mirrored), -turn(plain), atol=1e-9)


def test_reproduction_with_the_demonstrators_style_beats_the_class_mean(body, db):
    """Handed the true angles as the recovered ones, the adapted reproduction is closer to the demonstration
    than the class's mean trajectory (after DTW), for each class."""
    for i, label in enumerate(("walk", "squat", "kick")):
        motion = demonstrations(label, 1, np.random.default_rng(10 + i), subject=1002 + i, body=body)[0]
        rep = reproduce(db, body, label, _filtered_path(db, motion, label), 30.0, angles=motion.angles)
        mean = class_mean(db, body, label, motion.n_frames, 30.0)
        assert dtw_angle_rms_deg(rep.angles, motion.angles) < dtw_angle_rms_deg(mean.angles, motion.angles)
        assert dtw_mpjpe_mm(body, rep.qpos, body, motion.qpos) < dtw_mpjpe_mm(body, mean.qpos, body, motion.qpos)


def test_recovered_world_puts_a_camera_frame_motion_back_on_the_floor(body):
    motion = demonstrations("squat", 1, np.random.default_rng(5), subject=1004, body=body)[0]
    # A camera 3 m away, pitched down 20 degrees: world from camera, OpenCV axes as columns.
    pitch = np.deg2rad(20.0)
    fwd = np.array([np.cos(pitch), 0.0, -np.sin(pitch)])
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    rot = np.stack([right, np.cross(fwd, right), fwd], axis=1)
    centre = np.array([-3.0, 0.0, 1.5])
    cam = motion.qpos.copy()
    cam[:, :3] = (motion.base_pos - centre) @ rot
    cam[:, 3:7] = geometry.from_matrix(rot.T @ geometry.to_matrix(motion.base_quat))
    world = recovered_world(body, cam, gravity=rot.T @ np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose(world[:, 2], motion.base_pos[:, 2], atol=1e-9)       # heights above the floor
    np.testing.assert_allclose(world[:, :2] - world[0, :2], motion.base_pos[:, :2] - motion.base_pos[0, :2],
                               atol=1e-9)     # the camera looks along world x, as the recovered frame's x
    assert np.allclose(world[0, :2], 0.0)


def _monotone_paths(n, m, at=(0, 0)):
    """Every path of steps (1, 0), (0, 1), (1, 1) from ``at`` to (n - 1, m - 1)."""
    if at == (n - 1, m - 1):
        yield [at]
        return
    for da, db_ in ((1, 0), (0, 1), (1, 1)):
        nxt = (at[0] + da, at[1] + db_)
        if nxt[0] < n and nxt[1] < m:
            for rest in _monotone_paths(n, m, nxt):
                yield [at] + rest


def test_dtw_is_the_cheapest_monotone_alignment():
    rng = np.random.default_rng(6)
    for n, m in ((1, 1), (2, 3), (4, 3), (4, 4)):
        cost = rng.uniform(0, 1, size=(n, m))
        i, j = dtw_path(cost)
        best = min(sum(cost[a, b] for a, b in path) for path in _monotone_paths(n, m))
        assert cost[i, j].sum() == pytest.approx(best)
        assert (i[0], j[0]) == (0, 0) and (i[-1], j[-1]) == (n - 1, m - 1)
        assert np.all(np.diff(i) >= 0) and np.all(np.diff(j) >= 0)


def test_dtw_scores_forgive_timing_only(body):
    motion = demonstrations("kick", 1, np.random.default_rng(7), subject=1005, body=body)[0]
    slow = np.repeat(motion.angles, 2, axis=0)                        # the same poses at half the speed
    assert dtw_angle_rms_deg(slow, motion.angles) == 0.0
    assert dtw_angle_rms_deg(motion.angles + np.deg2rad(3.0), motion.angles) == pytest.approx(3.0)


def _command_inputs(tmp_path, body, db):
    from harness.scene.simulate import simulate
    from harness.scene.spec import MarkerSpec, SceneSpec

    motion = demonstrations("squat", 1, np.random.default_rng(8), subject=1006, body=body)[0]
    obs, truth = simulate(motion, SceneSpec(markers=MarkerSpec(60, 1)), np.random.default_rng(8), body)
    obs.save(tmp_path / "obs.npz")
    truth.save(tmp_path / "truth.npz")
    db.save(tmp_path / "db.npz")
    return motion, [str(tmp_path / "obs.npz"), "--database", str(tmp_path / "db.npz"), "--out",
                    str(tmp_path / "r.npz"), "--particles", "20"]


def test_reproduce_command_writes_the_motion(tmp_path, body, db, capsys):
    from harness.cli import main
    from harness.motion.motion import Motion

    motion, args = _command_inputs(tmp_path, body, db)
    assert main(["reproduce", *args, "--truth", str(tmp_path / "truth.npz"), "--scale", "0.9", "--mirror"]) == 0
    out = capsys.readouterr().out
    assert "repro_dtw_deg" in out and "class mean of" in out
    rep = Motion.load(tmp_path / "r.npz")
    assert rep.n_frames == motion.n_frames and "mirrored" in rep.source and "scaled 0.9" in rep.source
    assert main(["reproduce", *args, "--scale", "3"]) == 2
    assert "--scale must be in [0.5, 1.5]" in capsys.readouterr().err


@pytest.mark.slow
def test_reproduce_command_writes_the_video(tmp_path, body, db):
    from harness.cli import main

    _, args = _command_inputs(tmp_path, body, db)
    assert main(["reproduce", *args, "--video", str(tmp_path / "r.gif")]) == 0
    assert (tmp_path / "r.gif").stat().st_size > 10_000
