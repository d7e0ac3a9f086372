"""Subject mismatch (a scaled observed humanoid) and obstacles given by hand, from the body up to the command line."""

import numpy as np
import pandas as pd
import pytest
import yaml
from harness.motion.simple_walk import walk_motion

from harness import geometry
from harness.body import body_origins, geom_z_range
from harness.body.scaling import segment_factors
from harness.body.surface import geom_sdf
from harness.cli import main
from harness.evaluation import metrics
from harness.scene.occluders import custom_obstacles
from harness.scene.simulate import simulate
from harness.scene.spec import CameraSpec, OccluderGeom, OccluderSpec, SceneSpec, SubjectSpec
from harness.scene.subject import observed_motion
from harness.scene.visibility import OBSTACLE, OUTSIDE


@pytest.fixture(scope="module")
def walk(body):
    return walk_motion(body, 12)


def test_segment_factors_pair_left_and_right_and_repeat_by_seed(body):
    f = segment_factors(body.body_names, 1.05, 0.1, np.random.default_rng(3))
    g = segment_factors(body.body_names, 1.05, 0.1, np.random.default_rng(3))
    assert np.array_equal(f, g) and f[0] == 1.0
    assert f[body.body_id("lfemur")] == f[body.body_id("rfemur")] != f[body.body_id("ltibia")]
    assert np.all(np.abs(f[1:] / 1.05 - 1.0) <= 0.3 + 1e-12)          # clipped at 3 std
    assert np.all(segment_factors(body.body_names, 1.08, 0.0, np.random.default_rng(0))[1:] == 1.08)


def test_a_uniformly_scaled_subject_is_the_nominal_one_scaled(body, walk):
    spec = SceneSpec(camera=CameraSpec(azimuth=30.0), subject=SubjectSpec(scale=1.08))
    obs, truth = simulate(walk, spec, np.random.default_rng(0), body)
    subject = body.scaled(truth.segment_scale)
    np.testing.assert_allclose(truth.qpos[:, :3], 1.08 * walk.qpos[:, :3], atol=1e-12)
    np.testing.assert_allclose(truth.qpos[:, 3:], walk.qpos[:, 3:], atol=0)
    np.testing.assert_allclose(body_origins(subject, truth.qpos), 1.08 * body_origins(body, walk.qpos), atol=1e-9)
    # Markers lie on the scaled surface: signed distance 0 to their own geom of the subject.
    m = subject.model
    for k in range(len(truth.markers)):
        g = truth.markers.geom[k]
        rot = geometry.to_matrix(m.geom_quat[g])
        local = (truth.markers.local[k] - m.geom_pos[g]) @ rot
        assert abs(geom_sdf(int(m.geom_type[g]), m.geom_size[g], local[None])[0]) < 1e-9


def test_errors_are_measured_against_the_scaled_subjects_joints(body, walk):
    """The nominal body at the true angles and base pose against a 1.08 subject: the pose-only error is 8% of
    each joint's distance from the pelvis (a hand computation from the nominal joints)."""
    subject = body.scaled(np.full(body.model.nbody, 1.08))
    nominal = body_origins(body, walk.qpos, frame="base")[:, 1:]
    expected = 1000.0 * 0.08 * np.mean(np.linalg.norm(nominal, axis=-1))
    got = metrics.mpjpe_pose_mm(body, walk.qpos, walk.qpos, true_body=subject)
    assert got == pytest.approx(expected, rel=1e-9)
    assert metrics.mpjpe_pose_mm(body, walk.qpos, walk.qpos) == 0.0
    assert metrics.pa_mpjpe_mm(body, walk.qpos, walk.qpos, true_body=subject) < 1e-6   # a similarity removes it


def test_jittered_segments_keep_the_lowest_point_where_the_uniform_subject_has_it(body, walk):
    factors = segment_factors(body.body_names, 1.08, 0.1, np.random.default_rng(5))
    subject = body.scaled(factors)
    played = observed_motion(walk, body, subject, 1.08)
    low = geom_z_range(subject, played.qpos)[:, :, 0].min(axis=1)
    np.testing.assert_allclose(low, 1.08 * geom_z_range(body, walk.qpos)[:, :, 0].min(axis=1), atol=1e-9)


def test_obstacles_given_by_hand_stand_in_the_subjects_start_frame():
    geoms = (OccluderGeom("cylinder", (2.0, 0.5, 1.0), (0.2, 1.0), 0.0),
             OccluderGeom("box", (1.0, 0.0, 0.5), (0.1, 0.2, 0.5), 30.0))
    start, heading = np.array([3.0, -1.0, 0.95]), np.deg2rad(90.0)
    cyl, box = custom_obstacles(geoms, start, heading)
    np.testing.assert_allclose(cyl.centre, [3.0 - 0.5, -1.0 + 2.0, 1.0], atol=1e-12)   # x forward = world +y
    np.testing.assert_allclose(cyl.half, [0.2, 1.0, 0.0])
    assert cyl.kind == "cylinder" and box.yaw == pytest.approx(np.deg2rad(120.0))


def test_a_pillar_hides_what_its_lines_of_sight_cross(body, walk):
    """The ray caster's obstacle occlusion against an independent test: points sampled every millimetre along
    each line of sight, inside the cylinder by its signed distance."""
    pillar = OccluderGeom("cylinder", (1.6, 0.25, 1.0), (0.18, 1.0), 0.0)
    spec = SceneSpec(camera=CameraSpec(azimuth=0.0, elevation=5.0), occluders=OccluderSpec(geoms=(pillar,)))
    from harness.scene.setup import build_setup

    setup = build_setup(walk, spec, body)
    (ob,) = setup.occluders
    hidden = setup.visibility == OBSTACLE
    assert hidden.any() and (setup.visibility == 0).any()
    view = setup.visibility != OUTSIDE
    cams = np.broadcast_to(setup.camera.pos[:, None, :], setup.marker_world.shape)[view]
    pts = setup.marker_world[view]
    s = np.linspace(0.0, 1.0, 4000)[:, None, None]
    along = cams[None] + s * (pts - cams)[None]                         # (S, R, 3)
    inside = geom_sdf(ob.geom_type, ob.half, ob.to_local(along.reshape(-1, 3))).reshape(len(s), -1) < 0
    crosses = inside.any(axis=0)
    # A line of sight through the pillar is hidden by it (or, first, by the body itself).
    assert np.all(crosses[hidden[view]])
    assert np.mean(hidden[view] == crosses) > 0.97


def _tiny(tmp_path, extra: dict) -> str:
    raw = {
        "name": "tiny",
        "seed": 2,
        "database": {"classes": ["walk", "squat"], "train_demos": 3, "states": 6},
        "test": {"demos_per_class": 1},
        "markers": {"count": 50},
        "engine": {"tracks": {"particles": 40}, "model": {"points": 40}},
        "methods": ["full", "gt_base"],
    } | extra
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


def test_a_scaled_subject_runs_end_to_end(tmp_path):
    path = _tiny(tmp_path, {"subject": {"scale": 1.08}})
    assert main(["evaluate", path, "--results", str(tmp_path / "r"), "--quiet", "--limit", "1"]) == 0
    rows = pd.read_csv(tmp_path / "r" / "tiny" / "runs.csv")
    assert len(rows) == 2 and rows["mpjpe_cam_mm"].notna().all()
    assert rows.loc[rows["method"] == "gt_base", "base_pos_err_m"].max() < 1e-9      # the given pose is the truth


def test_obstacles_given_by_hand_run_end_to_end(tmp_path):
    geoms = [{"type": "box", "pos": [1.5, 0.0, 0.45], "size": [0.3, 0.7, 0.45]},
             {"type": "cylinder", "pos": [2.0, 0.8, 1.2], "size": [0.15, 1.2]}]
    path = _tiny(tmp_path, {"camera": {"azimuth": 0}, "occluders": {"geoms": geoms}})
    assert main(["evaluate", path, "--results", str(tmp_path / "r"), "--quiet", "--limit", "1"]) == 0
    rows = pd.read_csv(tmp_path / "r" / "tiny" / "runs.csv")
    assert (rows["obstacle_occlusion"] > 0.05).all()
