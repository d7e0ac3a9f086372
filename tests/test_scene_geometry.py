"""Scene: camera placement, occluder calibration, ray-cast visibility and geometric observations."""

import warnings

import mujoco
import numpy as np
import pytest
from harness.motion.simple_walk import walk_motion

from harness.body import forward_points
from harness.errors import HarnessError
from harness.observation import Observation
from harness.pinhole import project
from harness.scene.camera import camera_trajectory, camera_velocity
from harness.scene.occluders import Obstacle, preset_names, segments_blocked
from harness.scene.simulate import GroundTruth, SceneWarning, build_setup, simulate
from harness.scene.spec import (OCCLUDER_PRESETS, CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec,
                                SceneError, SceneSpec)
from harness.scene.visibility import OBSTACLE, OUTSIDE, SELF, VISIBLE, facing_away


@pytest.fixture(scope="module")
def walk(body):
    return walk_motion(body, 24)


def test_registered_presets_match_spec():
    assert set(preset_names()) == set(OCCLUDER_PRESETS)


def test_camera_azimuth_zero_is_in_front_and_ninety_on_the_left(walk):
    for az, expect in ((0.0, [1.0, 0.0]), (90.0, [0.0, 1.0])):
        traj = camera_trajectory(walk, CameraSpec(azimuth=az, elevation=0.0))
        offset = traj.pos[0, :2] - traj.look_at[0, :2]
        np.testing.assert_allclose(offset / np.linalg.norm(offset), expect, atol=1e-12)
        # The look-at point projects to the image centre.
        cam = traj.to_camera(traj.look_at[:1, None, :])[0, 0]
        np.testing.assert_allclose(project(traj.intrinsics, cam), [320.0, 240.0], atol=1e-9)
    np.testing.assert_allclose(traj.look_at[0, :2], walk.base_pos[:, :2].mean(axis=0))


def test_camera_pose_matches_mujoco_camera(body, walk):
    """The OpenCV rotation converted to MuJoCo's camera quaternion: MuJoCo's camera looks at the target."""
    setup = build_setup(walk, SceneSpec(camera=CameraSpec(azimuth=40.0, elevation=25.0)), body)
    traj, scene = setup.camera, setup.scene
    scene.pose(walk.qpos[0], traj.pos[0], traj.mujoco_quat()[0])
    xmat = scene.data.cam_xmat[scene.camera_id].reshape(3, 3)
    forward = -xmat[:, 2]                                  # MuJoCo cameras look along their -z
    target = traj.look_at[0] - traj.pos[0]
    np.testing.assert_allclose(forward, target / np.linalg.norm(target), atol=1e-9)
    np.testing.assert_allclose(scene.data.cam_xpos[scene.camera_id], traj.pos[0], atol=1e-12)


def test_orbit_camera_velocity_is_the_orbit_rate(walk):
    rate = 30.0
    traj = camera_trajectory(walk, CameraSpec(motion="orbit", orbit_rate=rate, elevation=0.0))
    vel = camera_velocity(traj, walk.fps)
    # Horizontal orbit: angular velocity about world z, which is -y in the (level) camera frame.
    np.testing.assert_allclose(vel[:, 3:], np.tile([0.0, -np.deg2rad(rate), 0.0], (len(vel), 1)), atol=1e-9)
    # Speed of the centre: radius times rate, perpendicular to the optical axis (central differences: sinc).
    speed = 4.0 * np.deg2rad(rate)
    h = np.deg2rad(rate) / walk.fps
    np.testing.assert_allclose(np.linalg.norm(vel[1:-1, :3], axis=1), speed * np.sin(h) / h, rtol=1e-9)
    np.testing.assert_allclose(vel[1:-1, 2], 0.0, atol=1e-9)


def test_segment_box_slab_test_against_dense_sampling(rng):
    box = Obstacle(np.array([1.0, 0.5, 0.4]), np.array([0.2, 0.3, 0.4]), 0.6)
    a = rng.uniform(-0.5, 2.5, (400, 3))
    b = rng.uniform(-0.5, 2.5, (400, 3))
    s = np.linspace(0.0, 0.999, 4000)
    pts = a[:, None] + s[None, :, None] * (b - a)[:, None]
    inside = (np.abs(box.to_local(pts)) <= box.half).all(axis=-1).any(axis=1)
    got = segments_blocked(a, b, [box])
    assert got.sum() > 40
    assert np.mean(got == inside) > 0.99


def test_ray_visibility_against_mj_ray_one_by_one(body, walk):
    setup = build_setup(walk, SceneSpec(camera=CameraSpec(azimuth=90.0), occluders=OccluderSpec("pillar", 0.3)),
                        body)
    m, d = setup.scene.model, setup.scene.data
    t = 7
    setup.scene.pose(walk.qpos[t])
    groups = np.array([1, 0, 0, 1, 0, 0], dtype=np.uint8)
    for i in range(len(setup.markers)):
        if setup.visibility[t, i] == OUTSIDE:
            continue
        vec = setup.marker_world[t, i] - setup.camera.pos[t]
        gid = np.array([-1], dtype=np.int32)
        hit = mujoco.mj_ray(m, d, setup.camera.pos[t], vec / np.linalg.norm(vec), groups, 1, -1, gid, None)
        blocked = 0 <= hit < np.linalg.norm(vec) - 2e-3
        away = setup.marker_normal[t, i] @ vec > 0.0
        expect = (OBSTACLE if m.geom_bodyid[gid[0]] == 0 else SELF) if blocked else (SELF if away else VISIBLE)
        assert setup.visibility[t, i] == expect, i


def test_marker_normals_move_with_their_bodies(body, walk):
    """World normals against an independent computation: the rigid motion of point + normal minus the point."""
    setup = build_setup(walk, SceneSpec(), body)
    mk = setup.markers
    tip = forward_points(body, walk.qpos, mk.body, mk.local + mk.normal)
    np.testing.assert_allclose(setup.marker_normal, tip - setup.marker_world, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(setup.marker_normal, axis=-1), 1.0, atol=1e-12)


def test_back_facing_markers_are_never_visible(body, walk):
    """The ray alone lets through back-facing markers whose chord through their own geom is under 2 mm."""
    setup = build_setup(walk, SceneSpec(camera=CameraSpec(azimuth=90.0)), body)
    away = facing_away(setup.camera, setup.marker_world, setup.marker_normal)
    assert not (away & (setup.visibility == VISIBLE)).any()
    # Some of them are caught only by the facing test: the ray reaches them before the tolerance.
    m, d = setup.scene.model, setup.scene.data
    groups = np.array([1, 0, 0, 1, 0, 0], dtype=np.uint8)
    n_ray_clear = 0
    for t in range(len(walk.qpos)):
        setup.scene.pose(walk.qpos[t])
        for i in np.flatnonzero(away[t] & (setup.visibility[t] == SELF)):
            vec = setup.marker_world[t, i] - setup.camera.pos[t]
            gid = np.array([-1], dtype=np.int32)
            hit = mujoco.mj_ray(m, d, setup.camera.pos[t], vec / np.linalg.norm(vec), groups, 1, -1, gid, None)
            n_ray_clear += not (0 <= hit < np.linalg.norm(vec) - 2e-3)
    assert n_ray_clear > 0


@pytest.mark.parametrize("preset", ["low_wall", "pillar", "boxes"])
def test_presets_reach_the_requested_obstacle_occlusion(body, walk, preset):
    spec = SceneSpec(camera=CameraSpec(azimuth=30.0), occluders=OccluderSpec(preset, 0.4, seed=2))
    _, truth = simulate(walk, spec, np.random.default_rng(0), body)
    assert abs(truth.obstacle_occlusion() - 0.4) <= 0.1
    assert truth.occluders
    if preset == "low_wall":   # a low wall hides feet before heads
        vis = truth.visibility
        assert (vis == OBSTACLE).any()


def test_side_view_reports_self_occlusion_separately(body, walk):
    _, truth = simulate(walk, SceneSpec(camera=CameraSpec(azimuth=90.0)), np.random.default_rng(0), body)
    assert truth.self_fraction.mean() > 0.2
    assert np.all(truth.obstacle_fraction == 0.0)
    n_view = (truth.visibility != OUTSIDE).sum(axis=1)
    np.testing.assert_allclose(truth.self_fraction, (truth.visibility == SELF).sum(axis=1) / n_view)


def test_geometric_flows_are_projected_marker_displacements(body, walk):
    spec = SceneSpec(observation=ObservationSpec(noise_px=0.0))
    obs, truth = simulate(walk, spec, np.random.default_rng(1), body)
    assert len(obs.flows[0]) == 0 and obs.camera_motion is None
    vis = truth.visibility == VISIBLE
    for t in (1, 12, 23):
        ids = truth.marker_ids[t]
        assert set(ids) == set(np.flatnonzero(vis[t - 1] & vis[t]))
        np.testing.assert_allclose(obs.flows[t][:, :2], truth.pixels[t, ids], atol=1e-9)
        np.testing.assert_allclose(obs.flows[t][:, 2:], (truth.pixels[t, ids] - truth.pixels[t - 1, ids]) * walk.fps,
                                   atol=1e-6)
    # Ground-truth base pose in the camera frame.
    base_cam = np.einsum("ji,j->i", truth.camera_rot[5], walk.base_pos[5] - truth.camera_pos[5])
    np.testing.assert_allclose(truth.base_pos_cam[5], base_cam, atol=1e-12)
    obs.validate()


def test_noise_dropout_outliers_statistics(body, walk):
    spec = SceneSpec(observation=ObservationSpec(noise_px=2.0, dropout=0.3, outliers=0.5))
    clean = SceneSpec(observation=ObservationSpec(noise_px=0.0))
    obs, truth = simulate(walk, spec, np.random.default_rng(3), body)
    obs0, truth0 = simulate(walk, clean, np.random.default_rng(3), body)
    n_true = sum((i >= 0).sum() for i in truth.marker_ids)
    n_all = sum(len(i) for i in truth0.marker_ids)
    assert 0.6 < n_true / n_all < 0.8                         # dropout 0.3
    n_out = sum((i < 0).sum() for i in truth.marker_ids)
    assert abs(n_out - 0.5 * n_all) < 0.05 * n_all           # outliers: half the visible count
    # Position noise: residual standard deviation ~ noise_px; flow noise ~ sqrt(2) noise_px * fps.
    res_p, res_v = [], []
    for t in range(1, len(obs)):
        ids = truth.marker_ids[t]
        ok = ids >= 0
        res_p.append(obs.flows[t][ok, :2] - truth.pixels[t, ids[ok]])
        res_v.append(obs.flows[t][ok, 2:] / walk.fps
                     - (truth.pixels[t, ids[ok]] - truth.pixels[t - 1, ids[ok]]))
    assert abs(np.concatenate(res_p).std() - 2.0) < 0.15
    assert abs(np.concatenate(res_v).std() - 2.0 * np.sqrt(2.0)) < 0.25


def test_same_seed_bit_identical_and_shuffled(body, walk):
    spec = SceneSpec(occluders=OccluderSpec("boxes", 0.3, seed=4),
                     observation=ObservationSpec(noise_px=1.0, dropout=0.1, outliers=0.1))
    a, ta = simulate(walk, spec, np.random.default_rng(9), body)
    b, tb = simulate(walk, spec, np.random.default_rng(9), body)
    c, _ = simulate(walk, spec, np.random.default_rng(10), body)
    for fa, fb in zip(a.flows, b.flows):
        assert fa.tobytes() == fb.tobytes()
    assert not all(np.array_equal(fa, fc) for fa, fc in zip(a.flows[1:], c.flows[1:]))
    assert any(not np.all(np.diff(i[i >= 0]) > 0) for i in ta.marker_ids[1:])   # rows are not in marker order


def test_moving_camera_fills_camera_motion_and_files_round_trip(body, walk, tmp_path):
    spec = SceneSpec(camera=CameraSpec(motion="follow", azimuth=90.0))
    obs, truth = simulate(walk, spec, np.random.default_rng(0), body)
    assert obs.camera_motion.shape == (len(walk.qpos), 6)
    # Seen from the subject's left (world +y), the camera's x axis (image right) is world -x, so following
    # a subject that walks along world +x is motion along the camera's own -x.
    np.testing.assert_allclose(obs.camera_motion[1:-1, 0], -walk.velocities.base_linear_world[1:-1, 0], atol=1e-9)
    obs.save(tmp_path / "o.npz")
    truth.save(tmp_path / "g.npz")
    back = GroundTruth.load(tmp_path / "g.npz")
    assert all(np.array_equal(x, y) for x, y in zip(back.marker_ids, truth.marker_ids))
    np.testing.assert_array_equal(back.visibility, truth.visibility)
    assert len(Observation.load(tmp_path / "o.npz")) == len(walk.qpos)


def test_bad_inputs_raise_harness_errors(body, walk):
    with pytest.raises(SceneError, match="markers.count"):
        MarkerSpec(count=0)
    with pytest.raises(SceneError, match="camera.width"):
        CameraSpec(width=0)
    with pytest.raises(SceneError, match="unknown preset"):
        OccluderSpec("fence", 0.2)
    with pytest.raises(SceneError, match="observation.mode"):
        ObservationSpec(mode="magic")
    # A camera following a subject that walks away from it passes through the wall in between.
    spec = SceneSpec(camera=CameraSpec(azimuth=180.0, elevation=-20.0, motion="follow", distance=1.6),
                     occluders=OccluderSpec("low_wall", 0.4))
    with pytest.raises(SceneError, match="inside occluder"):
        simulate(walk, spec, np.random.default_rng(0), body)
    # A camera inside the subject.
    with pytest.raises(SceneError, match="inside the subject"):
        simulate(walk, SceneSpec(camera=CameraSpec(distance=0.05, motion="follow")), np.random.default_rng(0),
                 body)
    assert issubclass(SceneError, HarnessError)


def test_camera_that_sees_nothing_gives_an_empty_observation_and_a_warning(body, walk):
    spec = SceneSpec(camera=CameraSpec(look_at_height=12.0, elevation=0.0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obs, truth = simulate(walk, spec, np.random.default_rng(0), body)
    assert any(issubclass(w.category, SceneWarning) for w in caught)
    assert obs.counts.sum() == 0 and np.all(truth.visibility == OUTSIDE)
    with pytest.raises(SceneError, match="sees none"):
        simulate(walk, SceneSpec(camera=spec.camera, occluders=OccluderSpec("pillar", 0.3)),
                 np.random.default_rng(0), body)


def test_camera_inside_the_body_by_bounding_spheres_is_the_signed_distance_test(body, walk):
    """``_camera_inside_body`` tests only the geoms whose bounding sphere holds the camera: the same answer as
    every geom's signed distance, for points spread over the posed body (many inside a geom) and around it."""
    from harness.body.surface import SurfacePoints, geom_sdf
    from harness.scene.model import SceneModel
    from harness.scene.visibility import _camera_inside_body

    scene = SceneModel(body, SurfacePoints(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3))),
                       [], 45.0, 64, 48)
    scene.pose(walk.qpos[5])
    m, d = scene.model, scene.data
    rng = np.random.default_rng(3)
    centres = d.geom_xpos[scene.body_geoms][rng.integers(0, len(scene.body_geoms), 300)]
    points = centres + rng.normal(0, 0.08, centres.shape)
    inside = 0
    for p in points:
        want = next((int(g) for g in scene.body_geoms
                     if geom_sdf(int(m.geom_type[g]), m.geom_size[g],
                                 ((p - d.geom_xpos[g]) @ d.geom_xmat[g].reshape(3, 3))[None])[0] <= 0.0), -1)
        assert _camera_inside_body(scene, p) == want
        inside += want >= 0
    assert 30 < inside < 270                    # both answers are exercised
