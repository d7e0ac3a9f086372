"""Retargeting: IK recovers humanoid56's own configurations; the whole path on a synthetic source."""

import numpy as np
import pytest

from harness import geometry
from harness.body import body_origins, forward_points
from harness.motion.ik import solve_ik
from harness.motion.retarget import RetargetError, retarget, y_up_to_z_up
from harness.motion.skeletons import SkeletonMappingError


def _pose(body, rng, n=3):
    q = body.qpos(body.random_angles(rng, n, scale=0.3))
    q[:, :3] += [0.2, -0.1, 0.0]
    q[:, 3:7] = geometry.exp(np.array([0.05, -0.05, 0.7]))
    return q


def test_ik_recovers_known_configuration(body, rng):
    # A motion from the zero pose to a random pose: each frame is warm-started from the one before.
    q = _pose(body, rng, 1)
    q = body.qpos(np.linspace(0.0, 1.0, 8)[:, None] * body.angles(q), q[0, :3], q[0, 3:7])
    ids = np.arange(1, body.model.nbody)
    targets = body_origins(body, q)
    solved, residual = solve_ik(body, targets, ids, body.zero_qpos(), posture=0.0, first_iterations=300,
                                iterations=60)
    assert residual.max() < 1e-3
    # Independent check of the residual: MuJoCo's own forward kinematics of the solution.
    np.testing.assert_allclose(forward_points(body, solved, ids, np.zeros((len(ids), 3))), targets, atol=1e-3)
    assert np.all(body.angles(solved) >= body.lower - 1e-12) and np.all(body.angles(solved) <= body.upper + 1e-12)


def test_y_up_conversion_is_a_rotation_not_a_mirror():
    basis = y_up_to_z_up(np.eye(3))
    assert np.linalg.det(basis) == pytest.approx(1.0)
    # CMU: x left, y up, z forward -> humanoid: y left, z up, x forward.
    np.testing.assert_array_equal(basis, [[0, 1, 0], [0, 0, 1], [1, 0, 0]])


def test_retarget_of_the_humanoid_itself_is_exact(body, rng):
    q = _pose(body, rng, 4)
    # A straight spine: the hips are placed on the base orientation estimated from the hips line and the
    # pelvis-to-thorax direction, which is the true base orientation only when the spine is straight.
    q[:, 7:16] = 0.0
    names = body.body_names[1:]
    # The humanoid as a y-up source in centimetres, 1.25 times larger: units, up axis and scale must cancel.
    src = body_origins(body, q) * 1.25 * 100.0
    src = np.stack([src[..., 1], src[..., 2], src[..., 0]], axis=-1)
    result = retarget(src, names, 30.0, unit_m=0.01, up="y", fps_out=None, body=body,
                      mapping={n: n for n in names}, posture=0.0, level_floor=False)
    assert result.scale == pytest.approx(0.8, rel=1e-9)
    assert result.residual.max() < 1e-3
    got = body_origins(body, result.qpos)
    want = body_origins(body, q)
    # Same pose up to the grounding shift (a constant vertical offset).
    shift = (got - want)[..., 2].mean()
    np.testing.assert_allclose(got - [0, 0, shift], want, atol=2e-3)


def test_retarget_resamples_before_solving(body, rng):
    q = _pose(body, rng, 13)
    names = body.body_names[1:]
    src = body_origins(body, q)
    result = retarget(src, names, 120.0, up="z", fps_out=30.0, body=body, mapping={n: n for n in names})
    assert result.qpos.shape == (4, 57) and result.fps == 30.0


def test_missing_hips_or_unmapped_joints_are_errors(body):
    src = np.zeros((3, 3, 3))
    with pytest.raises(RetargetError, match="lfemur, rfemur"):
        retarget(src, ("a", "b", "c"), 30.0, body=body, mapping={"a": "pelvis", "b": None, "c": None})
    with pytest.raises(SkeletonMappingError, match="Tail, Wing"):
        retarget(src, ("Hips", "Tail", "Wing"), 30.0, body=body)


def _lateral_signs(points: dict[str, np.ndarray], pairs: list[tuple[str, str]]) -> np.ndarray:
    """Per frame and pair, the sign of (left - right) . (up x forward): +1 when the pair's first point lies
    on the anatomical left. ``points[name]`` ``(T, 3)``; up from the pelvis to the head, forward from the
    ankles to the toe tips (both feet), so the sign depends only on the skeleton's own handedness."""
    u = points["head"] - points["pelvis"]
    f = points["ltoe"] + points["rtoe"] - points["lankle"] - points["rankle"]
    left = np.cross(u, f)
    return np.stack([np.sign(np.sum((points[a] - points[b]) * left, axis=1)) for a, b in pairs], axis=1)


PAIRS = [("lfemur", "rfemur"), ("ltibia", "rtibia"), ("lhumerus", "rhumerus"), ("lwrist", "rwrist")]


@pytest.mark.parametrize("name, start, source_names", [
    ("02_01.amc", 0, dict(zip(["pelvis", "head", "lankle", "rankle", "ltoe", "rtoe", "lfemur", "rfemur", "ltibia",
                               "rtibia", "lhumerus", "rhumerus", "lwrist", "rwrist"],
                              ["root", "head", "lfoot", "rfoot", "ltoes_end", "rtoes_end", "lfemur", "rfemur",
                               "ltibia", "rtibia", "lhumerus", "rhumerus", "lwrist", "rwrist"]))),
    ("131_02.bvh", 0, dict(zip(["pelvis", "head", "lankle", "rankle", "ltoe", "rtoe", "lfemur", "rfemur", "ltibia",
                                "rtibia", "lhumerus", "rhumerus", "lwrist", "rwrist"],
                               ["Hips", "Head", "LeftAnkle", "RightAnkle", "LeftToe_end", "RightToe_end",
                                "LeftHip", "RightHip", "LeftKnee", "RightKnee", "LeftShoulder", "RightShoulder",
                                "LeftWrist", "RightWrist"]))),
    ("09_01.bvh", 1, dict(zip(["pelvis", "head", "lankle", "rankle", "ltoe", "rtoe", "lfemur", "rfemur", "ltibia",
                               "rtibia", "lhumerus", "rhumerus", "lwrist", "rwrist"],
                              ["Hips", "Head", "LeftFoot", "RightFoot", "LeftToeBase_end", "RightToeBase_end",
                               "LeftUpLeg", "RightUpLeg", "LeftLeg", "RightLeg", "LeftArm", "RightArm",
                               "LeftHand", "RightHand"]))),
])
def test_retargeted_captures_are_not_mirrored(name, start, source_names, body):
    """The source's left joints land on humanoid56's l* bodies, on the humanoid's anatomical left: the
    side of each left/right pair, from the up x forward of each skeleton in its own coordinates, agrees
    frame by frame (a mirror would flip every sign)."""
    from harness.motion.asf_amc import asf_forward_kinematics, joint_names, load_amc, load_asf
    from harness.motion.bvh import CMU_BVH_UNIT_M, load_bvh
    from tests.conftest import require_mocap

    directory = require_mocap()
    if name.endswith(".bvh"):
        clip = load_bvh(directory / name)
        src, names, fps, unit = clip.positions(start, start + 90), clip.names, clip.fps, CMU_BVH_UNIT_M
    else:
        skeleton = load_asf(directory / "02.asf")
        src = asf_forward_kinematics(skeleton, load_amc(directory / name, skeleton), start, start + 90)
        names, fps, unit = joint_names(skeleton), 120.0, skeleton.unit_m
    result = retarget(src, names, fps, unit_m=unit, up="y", fps_out=30.0, body=body)
    # Source: its own coordinates (y-up, as captured), none of the retargeting's conversions involved;
    # 120 fps resampled at 30 fps keeps every 4th frame.
    src_signs = _lateral_signs({k: src[::4, names.index(v)] for k, v in source_names.items()}, PAIRS)
    # Humanoid: body origins and toe tips in its base frame.
    origins = body_origins(body, result.qpos, frame="base")
    hum = {k: origins[:, body.body_id(k) - 1] for k in ("pelvis", "head", *sum(PAIRS, ()))}
    hum["lankle"], hum["rankle"] = origins[:, body.body_id("lfoot") - 1], origins[:, body.body_id("rfoot") - 1]
    hum["ltoe"], hum["rtoe"] = forward_points(body, result.qpos, [body.body_id("ltoes"), body.body_id("rtoes")],
                                              [[0.08, 0.0, 0.0]] * 2, frame="base").transpose(1, 0, 2)
    hum_signs = _lateral_signs(hum, PAIRS)
    assert len(src_signs) == len(hum_signs) == 23
    np.testing.assert_array_equal(hum_signs, src_signs)
    # Walking and running keep each left joint on the left in most frames (a real, non-trivial check).
    assert np.all(np.mean(src_signs == 1.0, axis=0) > 0.9)
    # And humanoid56's convention: its base y axis points to its left.
    for a, b in PAIRS:
        assert np.mean(origins[:, body.body_id(a) - 1, 1] > origins[:, body.body_id(b) - 1, 1]) > 0.9


def test_sites_drive_toes_wrist_twist_and_hands(body, rng):
    """With the toe tips, knuckles and thumb tips as targets, the angles no joint centre can see (toes,
    wrist twist, hand flexion and deviation) are recovered; with joint centres alone they stay at zero."""
    from harness.motion.skeletons import SITES
    from harness.motion.retarget import target_points

    # Two frames of one pose (a second, different pose would test the warm start, not the sites).
    q = np.repeat(_pose(body, rng, 1), 2, axis=0)
    q[:, 7:16] = 0.0                       # straight spine, as in the exact-retarget test above
    hidden = [body.angle_index(n) for n in ("ltoes_y", "rtoes_y", "lwrist_z", "rwrist_z", "lhand_y", "lhand_x",
                                            "rhand_y", "rhand_x")]
    angles = body.angles(q)
    angles[:, hidden] = rng.uniform(-0.4, 0.4, len(hidden))
    q = body.qpos(angles, q[:, :3], q[:, 3:7])
    names = list(body.body_names[1:]) + list(SITES)
    ids, local = target_points(body, names)
    src = forward_points(body, q, ids, local)
    solved = {}
    for with_sites in (True, False):
        mapping = {n: (n if with_sites or n not in SITES else None) for n in names}
        result = retarget(src, names, 30.0, up="z", fps_out=None, body=body, mapping=mapping, posture=0.0,
                          level_floor=False)
        assert result.residual.max() < 2e-3
        assert len(result.target_bodies) == len(names) - (0 if with_sites else len(SITES))
        solved[with_sites] = body.angles(result.qpos)[:, hidden]
    np.testing.assert_allclose(solved[True], angles[:, hidden], atol=5e-3)
    assert np.abs(solved[False]).max() < 1e-6


def test_ground_height_ignores_a_single_dipping_frame(body):
    """Standing still (both feet in stance) with soles at 3 cm, one frame sunk to -5 cm: the floor is the
    stance percentile (3 cm), not the clip's minimum; the zero pose has its soles at pelvis height - 0.95 m."""
    from harness.motion.retarget import ground_height, stance_foot_heights

    q = np.repeat(body.zero_qpos()[None], 20, axis=0)
    q[:, 2] = 0.95 + 0.03
    q[7, 2] = 0.95 - 0.05
    np.testing.assert_allclose(stance_foot_heights(body, q, 30.0)[:20], np.where(np.arange(20) == 7, -0.05, 0.03),
                               atol=1e-9)
    assert ground_height(body, q, 30.0) == pytest.approx(0.03, abs=1e-9)
    assert ground_height(body, q, 30.0, percentile=0.0) == pytest.approx(-0.05, abs=1e-9)


def test_a_point_on_another_mapped_point_gives_no_target(body, rng):
    """An end site of zero length (Bandai's toe ends sit on the toe joints) has no direction: it is dropped, and
    the toes keep the angle the joints give them (zero here) instead of folding to put the tip on the joint."""
    from harness.motion.skeletons import SITES
    from harness.motion.retarget import target_points

    q = np.repeat(_pose(body, rng, 1), 2, axis=0)
    q[:, 7:16] = 0.0
    angles = body.angles(q)
    toes = [body.angle_index(n) for n in ("ltoes_y", "rtoes_y")]
    angles[:, toes] = 0.0
    q = body.qpos(angles, q[:, :3], q[:, 3:7])
    names = list(body.body_names[1:]) + ["ltoes_tip", "rtoes_tip"]
    ids, local = target_points(body, names)
    src = forward_points(body, q, ids, local)
    for side in ("l", "r"):        # the tip's source point on the toe joint, as in Bandai's skeleton
        src[:, names.index(f"{side}toes_tip")] = src[:, names.index(f"{side}toes")]
    result = retarget(src, names, 30.0, up="z", fps_out=None, body=body, mapping={n: n for n in names},
                      posture=0.0, level_floor=False)
    assert "ltoes_tip" not in result.target_bodies and "rtoes_tip" not in result.target_bodies
    assert len(result.target_bodies) == len(names) - 2 and set(SITES) & set(result.target_bodies) == set()
    np.testing.assert_allclose(body.angles(result.qpos)[:, toes], 0.0, atol=1e-3)
