"""The procedural performer: invariants over every primitive, base placement, variability, recognisability."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from harness.motion.nearest_class import (MIN_ACCURACY, TEST_SUBJECTS, TRAIN_SUBJECTS, make_set, nearest_class,
                                          time_normalise)
from harness import geometry
from harness.body import geom_z_range
from harness.cli import main as cli_main
from harness.errors import HarnessError
from harness.motion import Motion
from harness.motion.performer import (CLASSES, demonstrations, perform, place_base,
                                      subject_style)
from harness.body import forward_points
from harness.body.model import JOINT_NAMES
from harness.motion.primitives import (Take, UnknownPrimitiveError, lookup, mirror, registered, smooth_noise,
                                       soft_clip)

SEEDS = 20
FPS = 20.0          # a lower frame rate keeps the 200-demo sweep fast; placement does not depend on it
AIRBORNE = ("run", "jump", "jumping_jack")


@pytest.fixture(scope="module")
def sweep(body):
    """Every class, SEEDS demonstrations each: {label: [(motion, airborne mask), ...]}."""
    return {label: [perform(label, np.random.default_rng([7, c, s]), fps=FPS, body=body) for s in range(SEEDS)]
            for c, label in enumerate(CLASSES)}


def _foot_geoms(body):
    return np.array([mujoco.mj_name2id(body.model, mujoco.mjtObj.mjOBJ_GEOM, g)
                     for g in ("lfoot", "ltoes", "rfoot", "rtoes")])


def _lowest_foot(body, qpos):
    """(T, 2): lowest point of the left (foot, toes) and right (foot, toes) geoms, metres."""
    low = geom_z_range(body, qpos, _foot_geoms(body))[:, :, 0]
    return np.column_stack([low[:, :2].min(axis=1), low[:, 2:].min(axis=1)])


# --- registry and API ------------------------------------------------------------------------------

def test_the_ten_classes_are_registered():
    assert CLASSES == ("walk", "run", "jump", "squat", "kick", "punch", "wave", "bow", "throw", "jumping_jack")
    assert set(registered()) == set(CLASSES)


def test_joint_names_match_the_model(body):
    assert JOINT_NAMES == body.joint_names


def test_unknown_class_lists_the_valid_names(rng):
    with pytest.raises(UnknownPrimitiveError) as err:
        demonstrations("moonwalk", 1, rng)
    assert isinstance(err.value, HarnessError)
    assert "moonwalk" in str(err.value) and "jumping_jack" in str(err.value) and "walk" in str(err.value)


@pytest.mark.parametrize("kwargs", [dict(n=-1), dict(fps=0.0), dict(subject=-3)])
def test_bad_parameters_raise_harness_errors(rng, kwargs):
    args = dict(label="walk", n=1, rng=rng) | kwargs
    with pytest.raises(HarnessError):
        demonstrations(**args)


# --- invariants over every primitive -------------------------------------------------------------

def test_angles_within_joint_limits_for_every_class(body, sweep):
    for label, demos in sweep.items():
        for m, _ in demos:
            a = m.angles
            assert np.all(a >= body.lower) and np.all(a <= body.upper), label


def test_soft_clip_is_identity_inside_and_bounded_and_smooth():
    lo, hi = np.array([-1.0]), np.array([2.0])
    x = np.linspace(-5.0, 8.0, 20001)[:, None]
    y = soft_clip(x, lo, hi, margin=0.1)
    inside = (x > lo + 0.3) & (x < hi - 0.3)
    assert np.array_equal(y[inside], x[inside])
    assert np.all(y >= lo) and np.all(y <= hi)
    near = np.abs(x - np.clip(x, lo, hi)) < 0.5               # up to 5 margins outside: strictly inside
    assert np.all((y[near] > lo) & (y[near] < hi))
    assert np.all(np.diff(y[:, 0]) >= 0.0)                   # monotonic
    slope = np.diff(y[:, 0]) / np.diff(x[:, 0])
    assert np.max(np.abs(np.diff(slope))) < 1e-2             # C1: no kink where the saturation starts


def test_smooth_noise_has_the_requested_standard_deviation():
    rng = np.random.default_rng(3)
    noise = smooth_noise(rng, 60000, np.array([1.0, 4.0]), fps=30.0, smoothing_s=0.2)
    np.testing.assert_allclose(noise.std(axis=0), [1.0, 4.0], rtol=0.08)
    # Low-passed: neighbouring frames are almost equal (lag-1 correlation of a Gaussian filter of s samples
    # is exp(-1 / (4 s^2)) = 0.96 for s = 6).
    r = np.corrcoef(noise[1:, 0], noise[:-1, 0])[0, 1]
    assert abs(r - np.exp(-1.0 / (4 * 6.0**2))) < 0.01


def test_lowest_foot_point_on_the_floor_in_every_grounded_frame(body, sweep):
    for label, demos in sweep.items():
        for m, airborne in demos:
            low = _lowest_foot(body, m.qpos).min(axis=1)
            assert np.all(np.abs(low[~airborne]) < 0.01), label           # no sinking, no floating
            assert np.all(low > -1e-3), label                             # never through the floor
            assert geom_z_range(body, m.qpos)[:, :, 0].min() > -0.01, label   # no body part either
            if label not in AIRBORNE:
                assert not airborne.any(), label


def test_airborne_classes_leave_the_ground(body, sweep):
    for label in AIRBORNE:
        heights = [_lowest_foot(body, m.qpos).min(axis=1)[air].max() for m, air in sweep[label]]
        assert min(heights) > {"run": 0.01, "jump": 0.12, "jumping_jack": 0.02}[label], label


def test_supporting_foot_does_not_slide_when_walking(body, sweep):
    geoms = _foot_geoms(body)
    for m, _ in sweep["walk"][:5]:
        low = _lowest_foot(body, m.qpos)
        soles = np.empty((m.n_frames, 2, 2))
        for t, q in enumerate(m.qpos):
            body.data.qpos[:] = q
            mujoco.mj_kinematics(body.model, body.data)
            soles[t] = body.data.geom_xpos[geoms[[0, 2]], :2]
        for side, other in ((0, 1), (1, 0)):
            # frames where this foot clearly carries the body in both neighbouring frames
            support = (low[:, other] - low[:, side] > 0.03)
            both = support[1:] & support[:-1]
            slide = np.linalg.norm(np.diff(soles[:, side], axis=0), axis=1)[both]
            assert both.sum() > 5 and slide.max() < 0.01


def test_mirror_image_is_the_other_side(body):
    plan = lookup("wave")(Take(10.0, 1.0, 1.0, np.random.default_rng(0)))
    np.testing.assert_array_equal(mirror(mirror(plan)).angles, plan.angles)
    hands = [body.body_id("lhand"), body.body_id("rhand")]
    right = forward_points(body, body.qpos(np.deg2rad(plan.angles)), hands, np.zeros((2, 3)))
    left = forward_points(body, body.qpos(np.deg2rad(mirror(plan).angles)), hands, np.zeros((2, 3)))
    assert right[:, 1, 2].max() > right[:, 0, 2].max() + 0.3           # the wave raises the right hand
    # the mirrored wave puts the left hand where the right one was, reflected through y = 0
    np.testing.assert_allclose(left[:, 0], right[:, 1] * [1.0, -1.0, 1.0], atol=1e-9)


def test_same_seed_gives_bit_identical_motion(body):
    for label in CLASSES:
        a = demonstrations(label, 2, np.random.default_rng(11), body=body)
        b = demonstrations(label, 2, np.random.default_rng(11), body=body)
        for x, y in zip(a, b):
            assert np.array_equal(x.qpos, y.qpos) and x.subject == y.subject


def test_demonstrations_of_a_class_differ(sweep):
    for label, demos in sweep.items():
        a = time_normalise(demos[0][0].angles)
        for m, _ in demos[1:4]:
            rms = np.rad2deg(np.sqrt(np.mean((time_normalise(m.angles) - a) ** 2)))
            assert rms > 2.0, label


def test_same_subject_demonstrations_still_differ(body):
    a, b = demonstrations("punch", 2, np.random.default_rng(5), subject=3, body=body)
    n = min(a.n_frames, b.n_frames)
    assert a.subject == b.subject == "3"
    assert np.rad2deg(np.sqrt(np.mean((a.angles[:n] - b.angles[:n]) ** 2))) > 2.0


def test_subject_style_is_fixed_by_the_id():
    a, b, c = subject_style(4), subject_style(4), subject_style(5)
    assert np.array_equal(a.posture, b.posture) and a.tempo == b.tempo
    assert np.rad2deg(np.abs(a.posture - c.posture).max()) > 1.0


def test_start_pose_durations_and_travel(sweep):
    for label, demos in sweep.items():
        for m, _ in demos:
            assert np.allclose(m.base_pos[0, :2], 0.0) and abs(geometry.heading(m.base_quat[0])) < 1e-9
            assert 0.75 < m.duration < 3.8, (label, m.duration)
            assert np.linalg.norm(m.base_pos[:, :2], axis=1).max() < 3.3, label
            assert np.isfinite(m.velocities.qvel()).all()
            assert np.abs(m.velocities.angles).max() < 30.0, label     # rad/s: nothing snaps


def test_walk_advances_and_run_is_faster(sweep):
    def speeds(label):
        return np.array([m.base_pos[-1, 0] / m.duration for m, _ in sweep[label]])
    walk, run = speeds("walk"), speeds("run")
    assert np.all(walk > 0.45) and np.all(walk < 1.9)
    assert np.all(run > 1.6) and run.mean() > walk.mean() + 0.6
    assert np.all([abs(m.base_pos[-1, 1]) < 0.6 for m, _ in sweep["walk"]])
    assert np.mean([m.duration for m, _ in sweep["run"]]) < np.mean([m.duration for m, _ in sweep["walk"]])


def test_base_trajectories_match_the_action(body, sweep):
    standing = 0.95
    for m, _ in sweep["squat"]:
        assert m.base_pos[:, 2].min() < m.base_pos[0, 2] - 0.12   # pelvis lowered
    for m, air in sweep["jump"]:
        assert m.base_pos[air, 2].max() > m.base_pos[0, 2] + 0.12
    thorax = body.body_id("thorax")
    for m, _ in sweep["bow"]:
        tilt = []
        for q in m.qpos:
            body.data.qpos[:] = q
            mujoco.mj_kinematics(body.model, body.data)
            up = body.data.xmat[thorax].reshape(3, 3)[:, 2]
            tilt.append(np.degrees(np.arctan2(up[0], up[2])))      # > 0: leaning forward (+x)
        # A bend from a stance at most halfway down (the calibrated bow starts from the captured subject's
        # forward lean: CMU 13's bows start at 9-31 deg and bottom out at 79-92 deg), at least 35 deg deep.
        assert abs(tilt[0]) < 45.0 and max(tilt) > tilt[0] + 35.0


def test_place_base_keeps_a_standing_pose_still(body):
    n = 5
    angles = np.zeros((n, 50))
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    base = place_base(body, angles, quat, np.zeros(n, dtype=bool), fps=30.0)
    np.testing.assert_allclose(base, np.tile([0.0, 0.0, 0.95], (n, 1)), atol=1e-9)


def test_place_base_flies_a_ballistic_arc(body):
    # Standing pose, airborne in frames 10..19 at 20 fps: take-off at frame 9, landing at frame 20, so the
    # flight lasts T = 11 / 20 s and the apex is g T^2 / 8 above the standing height.
    n, fps = 30, 20.0
    flight = np.zeros(n, dtype=bool)
    flight[10:20] = True
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    base = place_base(body, np.zeros((n, 50)), quat, flight, fps, flight_speed=0.5)
    s = (np.arange(10, 20) - 9) / 11.0
    np.testing.assert_allclose(base[10:20, 2], 0.95 + 0.5 * 9.81 * (11 / fps) ** 2 * s * (1 - s), atol=1e-9)
    np.testing.assert_allclose(base[~flight, 2], 0.95, atol=1e-9)
    # no support motion to carry over: the only travel is flight_speed over the 11 airborne steps
    np.testing.assert_allclose(base[-1, :2], [0.5 * 11 / fps, 0.0], atol=1e-9)


def test_nearest_class_beats_chance_by_a_wide_margin():
    train = make_set(101, 3, TRAIN_SUBJECTS, fps=15.0)
    test = make_set(102, 3, TEST_SUBJECTS, fps=15.0)
    confusion, acc = nearest_class(train, test)
    assert confusion.sum() == len(test) and acc >= MIN_ACCURACY


# --- the render-motion command --------------------------------------------------------------------

def test_render_motion_rejects_bad_input(tmp_path, capsys):
    assert cli_main(["render-motion", "--class", "moonwalk", "--sheet", str(tmp_path / "a.png")]) == 2
    assert "moonwalk" in capsys.readouterr().err
    assert cli_main(["render-motion", "--class", "walk", "--out", str(tmp_path / "a.avi")]) == 2
    assert cli_main(["render-motion", "--motion", str(tmp_path / "missing.npz"), "--stills", str(tmp_path)]) == 2


def test_render_motion_writes_stills_and_a_sheet(tmp_path, body):
    m = demonstrations("wave", 1, np.random.default_rng(0), fps=10.0, body=body)[0]
    path = tmp_path / "wave.npz"
    m.save(path)
    assert Motion.load(path).n_frames == m.n_frames
    code = cli_main(["render-motion", "--motion", str(path), "--stills", str(tmp_path / "s"), "--n-stills", "2",
                     "--sheet", str(tmp_path / "sheet.png"), "--sheet-frames", "3", "--width", "64",
                     "--height", "64"])
    assert code == 0
    assert len(list((tmp_path / "s").glob("*.png"))) == 2
    import cv2
    sheet = cv2.imread(str(tmp_path / "sheet.png"))
    assert sheet.shape == (64, 3 * 64, 3) and sheet.std() > 5.0      # an image, not a blank
