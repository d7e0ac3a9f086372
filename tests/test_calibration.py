"""The performer's calibration on captures: the table, how the performer applies it, the split, the fit."""

import numpy as np
import pytest

from harness.body.model import JOINT_NAMES
from harness.motion import Motion
from harness.motion.calibration import (NEUTRAL, CalibrationError, ClassCalibration, read_calibration,
                                        save_calibration)
from harness.motion.performer import CLASSES, guarantee_violations, perform, subject_style
from harness.motion.realism import (acting_side, calibration_split, fit_class, joint_distances, procedural_set)


def _cal(**changes) -> ClassCalibration:
    fields = dict(posture=np.zeros(50), gain=np.ones(50), lean=np.zeros(2), lean_gain=np.ones(2), extent=1.0,
                  left=0.0)
    fields.update(changes)
    return ClassCalibration(**fields)


def test_table_round_trip_and_errors(tmp_path):
    cal = _cal(posture=np.linspace(-5, 5, 50), gain=np.linspace(0.5, 1.5, 50), lean=np.array([3.0, -1.0]),
               lean_gain=np.array([1.2, 0.8]), extent=0.7, left=0.25)
    path = tmp_path / "cal.json"
    save_calibration(path, {"kick": cal}, {"note": "test"})
    back = read_calibration(path)["kick"]
    np.testing.assert_allclose(back.posture, cal.posture, atol=1e-3)
    np.testing.assert_allclose(back.gain, cal.gain, atol=1e-4)
    assert (back.extent, back.left) == (0.7, 0.25) and np.allclose(back.lean, [3.0, -1.0])
    path.write_text('{"classes": {"kick": {"posture": [0, 1]}}}')
    with pytest.raises(CalibrationError, match="class 'kick'"):
        read_calibration(path)
    with pytest.raises(CalibrationError, match="no such calibration file"):
        read_calibration(tmp_path / "absent.json")


def test_posture_and_gain_act_as_documented(body):
    """Same seed and subject: a class posture adds its degrees to every frame of a joint the primitive leaves
    alone; a gain of 2 doubles what the primitive writes into a joint (the squat's lower-back flexion) (checked inside the joint ranges, where
    the soft clip is the identity)."""
    head, knee = JOINT_NAMES.index("head_z"), JOINT_NAMES.index("lowerback_y")
    take = lambda cal: np.rad2deg(perform("squat", np.random.default_rng(3), subject=4, body=body,  # noqa: E731
                                          calibration=cal)[0].angles)
    base, carriage = take(_cal()), subject_style(4).carriage
    posture = np.zeros(50)
    posture[head] = 6.0
    np.testing.assert_allclose(take(_cal(posture=posture))[:, head] - base[:, head], 6.0 * carriage, atol=1e-6)
    gain = np.ones(50)
    gain[knee] = 2.0
    doubled = take(_cal(gain=gain))[:, knee]
    rest = np.rad2deg(perform("squat", np.random.default_rng(3), subject=4, body=body,
                              calibration=_cal(gain=np.where(np.arange(50) == knee, 0.0, 1.0)))[0].angles)[:, knee]
    # The soft clip is the identity more than 8 % of the range (7 deg) inside the lower back's [-30, 60] deg.
    inside = np.all([(x > -22.0) & (x < 52.0) for x in (doubled, base[:, knee], rest)], axis=0)
    assert inside.sum() > 10 and np.ptp(base[:, knee] - rest) > 3.0
    np.testing.assert_allclose((doubled - rest)[inside], 2.0 * (base[:, knee] - rest)[inside], atol=1e-6)


def test_left_share_mirrors_exactly_the_subjects_below_it(body):
    """A left share of 0.5: the subjects whose laterality is below it kick with the left leg, the others with
    the right (``acting_side`` read from the angles alone)."""
    takes = procedural_set("kick", 16, 9, _cal(left=0.5))
    want = ["l" if subject_style(int(m.subject)).laterality < 0.5 else "r" for m in takes]
    assert 0 < want.count("l") < len(want)
    assert [acting_side(m) for m in takes] == want


def test_split_by_subject_then_by_take_then_by_halves():
    def motion(label, subject, stem, i):
        return Motion(qpos=np.tile(np.r_[0, 0, 1, 1, 0, 0, 0, np.zeros(50)], (2, 1)), fps=30.0, label=label,
                      subject=subject, demo=f"{stem}:{i}-{i + 1}")
    ms = [motion("walk", "131", "131_02", 0), motion("walk", "2", "02_01", 0), motion("walk", "2", "02_02", 0),
          motion("bow", "13", "13_29", 0), motion("bow", "13", "13_29", 5), motion("bow", "13", "13_31", 0),
          motion("punch", "2", "02_05", 0), motion("punch", "2", "02_05", 1), motion("punch", "2", "02_05", 2)]
    calibrate, report = calibration_split(ms)
    assert [m.demo for m in calibrate] == ["02_01:0-1", "02_02:0-1", "13_29:0-1", "13_29:5-6", "02_05:0-1",
                                           "02_05:1-2"]
    assert [m.demo for m in report] == ["131_02:0-1", "13_31:0-1", "02_05:2-3"]


def test_joint_distance_is_the_shift_of_a_shifted_copy(body):
    takes = procedural_set("wave", 2, 4, NEUTRAL)
    shifted = [m.replace(qpos=np.concatenate([m.qpos[:, :7], m.qpos[:, 7:] + np.deg2rad(5.0)], axis=1))
               for m in takes]
    np.testing.assert_allclose(joint_distances(takes, shifted), 5.0, atol=1e-9)


def test_fit_recovers_a_known_calibration():
    """'Real' takes made with a known class posture and gains: the fit, started from the uncalibrated
    performer, brings the joint distance down and recovers the posture where it was set."""
    truth = np.zeros(50)
    truth[JOINT_NAMES.index("lowerback_x")] = 8.0
    truth[JOINT_NAMES.index("rradius_y")] = -30.0
    gain = np.ones(50)
    gain[JOINT_NAMES.index("lhumerus_x")] = 0.6
    real = procedural_set("jumping_jack", 16, 21, _cal(posture=truth, gain=gain))
    fitted = fit_class(real, "jumping_jack", n_takes=16, iterations=3, seed=0)
    before = joint_distances(real, procedural_set("jumping_jack", 16, 0, NEUTRAL)).mean()
    after = joint_distances(real, procedural_set("jumping_jack", 16, 0, fitted)).mean()
    assert after < 0.6 * before
    for name in ("lowerback_x", "rradius_y"):
        j = JOINT_NAMES.index(name)
        assert fitted.posture[j] == pytest.approx(truth[j], abs=4.0), name
    assert fitted.gain[JOINT_NAMES.index("lhumerus_x")] == pytest.approx(0.6, abs=0.15)


def test_guarantees_flag_a_body_part_through_the_floor(body):
    motion, _ = perform("squat", np.random.default_rng(1), body=body)
    assert guarantee_violations(motion, body) == []
    sunk = motion.replace(qpos=motion.qpos - np.r_[0, 0, 0.05, np.zeros(54)])
    assert any("below the floor" in v for v in guarantee_violations(sunk, body))


@pytest.mark.parametrize("label", CLASSES)
def test_shipped_table_keeps_the_guarantees(label, body):
    """Every class of the shipped table keeps the performer's guarantees on takes the fit never saw."""
    for m in procedural_set(label, 6, 77):
        assert guarantee_violations(m, body) == [], (label, m.subject)


def test_a_joint_a_capture_holds_still_is_left_out_of_its_distance(body):
    """A real set whose one demonstration holds a joint at zero (a BVH wrist): the joint's distance is the one
    to the demonstrations that measure it; a joint no demonstration measures has none (NaN), unless all joints
    are asked for (``measured_only=False``, where the constant counts)."""
    takes = procedural_set("wave", 2, 4, NEUTRAL)
    j, k = JOINT_NAMES.index("rwrist_z"), JOINT_NAMES.index("lwrist_z")
    held = []
    for m in takes:
        q = np.array(m.qpos)
        q[:, 7 + k] = 0.0
        held.append(m.replace(qpos=q))
    q = np.array(takes[1].qpos)
    q[:, 7 + j] = 0.0
    partly = [takes[0], takes[1].replace(qpos=q)]
    procedural = procedural_set("wave", 3, 5, NEUTRAL)
    d = joint_distances(held, procedural)
    assert np.isnan(d[k]) and not np.isnan(d).sum() > 1
    assert joint_distances(held, procedural, measured_only=False)[k] > 0
    np.testing.assert_allclose(joint_distances(partly, procedural)[j], joint_distances(takes[:1], procedural)[j])
