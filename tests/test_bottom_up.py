"""The bottom-up posture estimator (``harness.engine.bottom_up``): the shipped model, its features, the twin's
canonical form, the numpy network against scikit-learn's, and its use in the engine."""

import json

import numpy as np
import pytest

from harness import geometry
from harness.engine import bottom_up
from harness.engine.bottom_up import (MODEL_PATH, N_FEATURES, N_OUTPUTS, BottomUpModel, canonical, decode, fuse,
                                      rotation_from_axes, targets, window_features)
from harness.engine.features import mirror_features
from harness.engine.track import twin
from harness.pinhole import Intrinsics

INTR = Intrinsics(640, 480, 579.4, 579.4, 320.0, 240.0)


def _flows(rng, n=60, centre=(300.0, 250.0), extent=200.0):
    pos = np.array(centre) + rng.normal(size=(n, 2)) * [0.25 * extent, 0.3 * extent]
    return np.concatenate([pos, rng.normal(size=(n, 2)) * 40.0], axis=1)


def test_the_shipped_model_loads_without_pickle_and_maps_features_to_outputs():
    with np.load(MODEL_PATH, allow_pickle=False) as z:
        assert int(z["layers"]) >= 2
    model = BottomUpModel.load()
    scores = json.loads(model.info)["scores"]
    assert {"rotation_deg", "angles_rms_rad", "depth_rel_median"} <= set(scores)
    y, std = model.predict(np.zeros((3, N_FEATURES)))
    assert y.shape == std.shape == (3, N_OUTPUTS)
    assert np.all(np.isfinite(y)) and np.all(std > 0)
    assert MODEL_PATH.stat().st_size < 3_000_000       # small enough to ship


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_the_numpy_network_is_scikit_learns():
    from sklearn.neural_network import MLPRegressor

    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(64, N_FEATURES)), rng.normal(size=(64, N_OUTPUTS))
    net = MLPRegressor(hidden_layer_sizes=(16, 8), max_iter=20, random_state=0).fit(x, y)
    rest = dict(x_mean=np.zeros(N_FEATURES), x_std=np.ones(N_FEATURES), y_mean=np.zeros(N_OUTPUTS),
                y_std=np.ones(N_OUTPUTS), residual_std=np.ones(N_OUTPUTS), scale_w=np.zeros((8, 6)), scale_b=np.zeros(6))
    model = BottomUpModel(net.coefs_, net.intercepts_, **rest)
    np.testing.assert_allclose(model.hidden_and_outputs(x[:5])[1], net.predict(x[:5]), rtol=1e-9, atol=1e-12)
    # and after the export's single precision, within its rounding
    again = BottomUpModel(*[[a.astype(np.float32).astype(float) for a in part] for part in (net.coefs_,
                                                                                             net.intercepts_)], **rest)
    np.testing.assert_allclose(again.hidden_and_outputs(x[:5])[1], net.predict(x[:5]), atol=1e-4)


def test_a_model_of_the_wrong_size_is_refused():
    with pytest.raises(Exception, match="maps"):
        BottomUpModel([np.zeros((10, 4)), np.zeros((4, N_OUTPUTS))], [np.zeros(4), np.zeros(N_OUTPUTS)],
                      **dict.fromkeys(("x_mean", "x_std", "y_mean", "y_std", "residual_std", "scale_w", "scale_b")))


def test_features_ignore_the_flows_order_and_where_the_body_is():
    rng = np.random.default_rng(1)
    window = [_flows(rng) for _ in range(5)]
    x, centre, scale = window_features(window, INTR, 30.0)
    assert x.shape == (N_FEATURES,)
    shuffled = [f[rng.permutation(len(f))] for f in window]
    np.testing.assert_allclose(window_features(shuffled, INTR, 30.0)[0], x, atol=1e-12)
    # the whole window moved in the image: only the centre's ray (the first two globals) changes
    moved = [f + [40.0, -25.0, 0.0, 0.0] for f in window]
    y = window_features(moved, INTR, 30.0)[0]
    np.testing.assert_allclose(y[:-5], x[:-5], atol=1e-9)
    np.testing.assert_allclose(y[-5:-3], x[-5:-3] + [40.0 / INTR.fx, -25.0 / INTR.fy], atol=1e-9)
    # the body twice as large (twice as near): positions and velocities scale, only log(s / f) changes
    big = [np.concatenate([centre + 2.0 * (f[:, :2] - centre), 2.0 * f[:, 2:]], axis=1) for f in window]
    z = window_features(big, INTR, 30.0)[0]
    np.testing.assert_allclose(z[:-5], x[:-5], atol=1e-9)
    assert z[-3] == pytest.approx(x[-3] + np.log(2.0))


def test_too_few_flows_give_no_estimate():
    rng = np.random.default_rng(2)
    assert window_features([_flows(rng), _flows(rng, n=3)], INTR, 30.0) is None


def test_the_canonical_pose_faces_the_camera_and_the_twin_pair_shares_it():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = geometry.normalize(rng.normal(size=4))
        rot = geometry.to_matrix(q)
        feats = rng.normal(size=106)
        rot_c, feat_c, took_twin = canonical(rot, feats)
        assert rot_c[2, 0] <= 0
        # the twin as the tracker makes it (quaternions, track.twin) has the same canonical form
        rot_t = geometry.to_matrix(twin(q[None])[0])
        rot_tc, feat_tc, _ = canonical(rot_t, mirror_features(feats))
        np.testing.assert_allclose(rot_tc, rot_c, atol=1e-9)
        np.testing.assert_allclose(feat_tc, feat_c, atol=1e-12)
        np.testing.assert_allclose(feat_c, mirror_features(feats) if took_twin else feats)


def test_decoding_a_target_gives_back_the_pose():
    rng = np.random.default_rng(4)
    rot = geometry.to_matrix(geometry.normalize(rng.normal(size=4)))
    pos = np.array([0.4, 0.3, 4.5])
    feats = rng.normal(size=106)
    centre, scale = np.array([330.0, 260.0]), 180.0
    y = targets(rot, pos, feats, centre, scale, INTR)
    est = decode(y, np.ones(N_OUTPUTS), centre, scale, INTR)
    np.testing.assert_allclose(est.position, pos, atol=1e-9)
    np.testing.assert_allclose(est.rotation, canonical(rot, feats)[0], atol=1e-9)
    (r0, f0), (r1, f1) = est.pose_modes()
    np.testing.assert_allclose(rotation_from_axes(np.concatenate([r1[:, 0], r1[:, 1]])), r1, atol=1e-12)
    # a track at either mode gets that mode's posture
    np.testing.assert_allclose(est.posture_near(r1)[0], f1)
    np.testing.assert_allclose(est.posture_near(r0)[0], f0)


def test_fuse_is_the_product_of_gaussians():
    rng = np.random.default_rng(5)
    a, va, b, vb = rng.normal(size=4), rng.uniform(0.1, 1, 4), rng.normal(size=4), rng.uniform(0.1, 1, 4)
    mean, var = fuse(a, va, b, vb, 0.5)
    grid = np.linspace(-8, 8, 200001)
    for i in range(4):
        log_p = -0.5 * (grid - a[i]) ** 2 / va[i] - 0.25 * (grid - b[i]) ** 2 / vb[i]
        p = np.exp(log_p - log_p.max())
        p /= p.sum()
        assert np.sum(p * grid) == pytest.approx(mean[i], abs=1e-6)
        assert np.sum(p * (grid - mean[i]) ** 2) == pytest.approx(var[i], rel=1e-4)


def test_the_first_cloud_takes_its_share_about_both_modes():
    from harness.engine.config import BottomUpSettings
    from harness.engine.frame import Frame
    from harness.engine.particle_filter import ParticleCloud
    from harness.engine.pose_source import ParticleTracks

    rng = np.random.default_rng(6)
    rot = geometry.to_matrix(geometry.normalize(np.array([0.3, 0.1, -0.9, 0.2])))
    rot = canonical(rot, np.zeros(106))[0]
    est = bottom_up.PostureEstimate(rot, np.array([0.1, 0.2, 4.0]), np.zeros(106), np.ones(106), 0.01, 0.01)
    source = ParticleTracks.__new__(ParticleTracks)
    source.rng, source.bottomup_settings = rng, BottomUpSettings(spawn_share=0.5, spawn_rotation_std=0.05,
                                                                 spawn_depth_std=0.05)
    n = 400
    wide = ParticleCloud(np.tile([0.0, 0.0, 3.0], (n, 1)), np.tile([1.0, 0, 0, 0], (n, 1)), np.full(n, -np.log(n)))
    frame = Frame(0, INTR, 30.0, np.zeros((0, 4)), posture=est)
    out = source.with_bottom_up(wide, frame)
    assert len(out) == n
    np.testing.assert_allclose(out.positions[:200], wide.positions[:200])
    drawn = geometry.to_matrix(out.quats[200:])
    (r0, _), (r1, _) = est.pose_modes()
    near = np.minimum(np.degrees(np.arccos(np.clip((np.einsum("nij,ij->n", drawn, r0) - 1) / 2, -1, 1))),
                      np.degrees(np.arccos(np.clip((np.einsum("nij,ij->n", drawn, r1) - 1) / 2, -1, 1))))
    assert np.percentile(near, 95) < 20.0
    twin_share = np.mean(np.einsum("nij,ij->n", drawn, r1) > np.einsum("nij,ij->n", drawn, r0))
    assert 0.35 < twin_share < 0.65
    ratio = out.positions[200:, 2] / 4.0
    assert 0.8 < np.median(ratio) < 1.2
    # the draws stay on the estimate's ray: the image point does not move
    np.testing.assert_allclose(out.positions[200:, :2] / out.positions[200:, 2:], [[0.1 / 4.0, 0.2 / 4.0]] * 200,
                               atol=1e-12)
    assert source.with_bottom_up(wide, Frame(0, INTR, 30.0, np.zeros((0, 4)))) is wide


def test_re_injections_alternatives_turn_a_track_onto_each_mode():
    from harness.engine.config import BottomUpSettings, ReinjectionSettings
    from harness.engine.frame import Frame
    from harness.engine.pose_source import ParticleTracks
    from harness.engine.track import Track

    heading = geometry.to_matrix(geometry.yaw(np.array([0.7])))[0]
    parent_rot = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]).T     # upright, level camera
    mode = canonical(parent_rot @ heading, np.zeros(106))[0]
    est = bottom_up.PostureEstimate(mode, np.array([0.0, 0.5, 5.0]), np.zeros(106), np.ones(106), 0.1, 0.1)
    source = ParticleTracks.__new__(ParticleTracks)
    source.bottomup_settings, source.reinjection_settings = BottomUpSettings(), ReinjectionSettings()
    parent = Track(0, "lead", None)
    parent.pose = (np.array([0.0, 0.4, 4.0]), geometry.from_matrix(parent_rot))
    alts = source.bottom_up_alternatives(parent, Frame(0, INTR, 30.0, np.zeros((0, 4)), posture=est))
    assert [a.name for a in alts] == ["bottomup0", "bottomup1"]
    for alt, (rot, _) in zip(alts, est.pose_modes()):
        pos, quat = alt.apply(parent.pose[0][None], parent.pose[1][None], None)
        assert pos[0, 2] == pytest.approx(5.0)
        turned = geometry.to_matrix(quat)[0]
        # the turn about the parent's vertical brings its forward axis onto the mode's, seen from above
        f, g = turned[:, 0], rot[:, 0]
        assert np.degrees(abs(np.arctan2(f[2], f[0]) - np.arctan2(g[2], g[0]))) % 360 == pytest.approx(0, abs=1e-6)
    assert source.bottom_up_alternatives(parent, Frame(0, INTR, 30.0, np.zeros((0, 4)))) == []
