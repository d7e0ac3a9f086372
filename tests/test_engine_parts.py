"""Engine parts against independent computations: hmmlearn's forward algorithm, brute-force mixtures,
resampling statistics, Gauss-Newton on a noiseless pose."""

import ast
import pathlib

import numpy as np
import pytest
from hmmlearn.hmm import GaussianHMM

from engine_fixtures import CLASSES, synthetic_demos
from harness import geometry
from harness.body import forward_points, forward_points_and_jacobians, sample_surface
from harness.engine import MotionDatabase, Recognizer, motion_features, recognize_features
from harness.engine.likelihood import (FlowModel, flow_log_likelihoods, responsibilities, tempered,
                                       velocity_log_likelihoods)
from harness.engine.particle_filter import (ParticleCloud, ProcessNoise, camera_pitch, effective_sample_size,
                                            motion_mean, pose_mixture_log_density, propose, propose_many,
                                            reweight_many, settled, systematic_resample, upright_orientations)
from harness.engine.open_region import OpenMask
from harness.engine.recovery import Prior, Recovery, fit_without_database, refine_pose
from harness.engine.transform import ImageDistributions, patch_std
from harness.engine.vector_math import EXP32_MIN, LOG_MIN, atan_ratio, exp32_parts, exp_into, log_normal
from harness.errors import EngineError
from harness.pinhole import Intrinsics, project, projection_jacobian


@pytest.fixture(scope="module")
def database(body):
    rng = np.random.default_rng(1)
    train = [m for c in CLASSES for m in synthetic_demos(body, c, 4, rng)]
    return MotionDatabase(n_states=8, cyclic=("march",), n_iter=5).fit(train)


def test_database_is_left_to_right_and_round_trips(database, tmp_path):
    db = database
    assert list(db.classes_) == sorted(CLASSES)
    upper = np.triu(np.ones((8, 8)), 0) - np.triu(np.ones((8, 8)), 2)   # self and next only
    march = list(db.classes_).index("march")
    for c in range(3):
        allowed = upper.copy()
        if c == march:
            allowed[-1, 0] = 1
        allowed = np.kron(np.eye(2), allowed)     # each side's chain on its own (both-handed database)
        assert np.all(db.transmat_[c][allowed == 0] == 0)
        np.testing.assert_allclose(db.transmat_[c].sum(axis=1), 1.0)
    assert np.all(db.covars_ >= np.deg2rad(2.0) ** 2 * 0.999)
    db.save(tmp_path / "db.npz")
    back = MotionDatabase.load(tmp_path / "db.npz")
    for name in ("means_", "covars_", "transmat_", "startprob_"):
        np.testing.assert_array_equal(getattr(back, name), getattr(db, name))
    assert back.cyclic == db.cyclic and back.fps_ == db.fps_


def test_forward_recursion_matches_hmmlearn(database, body):
    """The class posterior after T frames equals normalised per-class likelihoods from hmmlearn's score."""
    db = database
    m = synthetic_demos(body, "squat", 1, np.random.default_rng(5))[0]
    f = motion_features(m)
    post = recognize_features(db, f, start_spread=0.0, outlier=0.0)
    scores = []
    for c in range(db.n_classes):
        hmm = GaussianHMM(n_components=db.means_.shape[1], covariance_type="diag")
        hmm.startprob_, hmm.transmat_ = db.startprob_[c], db.transmat_[c]
        hmm.means_, hmm.covars_ = db.means_[c], db.covars_[c]
        scores.append(hmm.score(f))
    scores = np.array(scores)
    expect = np.exp(scores - scores.max())
    np.testing.assert_allclose(post[-1], expect / expect.sum(), atol=1e-9)
    assert db.classes_[post[-1].argmax()] == "squat"


def test_recognizer_pruning_and_empty_frames(database):
    rec = Recognizer(database, start_spread=0.05, prune=0.01)
    rec.log_alpha[0] -= 50.0   # an unlikely primitive still follows its own best states
    before = rec.posterior.copy()
    rec.update(None)            # no evidence: the belief does not change
    np.testing.assert_allclose(rec.posterior, before / before.sum())
    # Only the start states are worth evaluating: the first state of each side's chain, per primitive.
    assert rec.active().sum() == 6 and rec.active()[:, [0, 8]].all()
    with pytest.raises(EngineError, match="emissions must be"):
        rec.update(np.zeros((2, 2)))


def test_the_compiled_recursion_equals_its_numpy_definition(database):
    """Each step of the recursion (transitions, emissions folded in and normalised, the derived posteriors and
    the active states) against the formulas written in numpy, over frames of random emissions, for a belief
    over every primitive and one restricted to two (the others -inf throughout)."""
    rng = np.random.default_rng(3)
    for restrict in (None, [0, 2]):
        rec = Recognizer(database, start_spread=0.05, prune=1e-4)
        if restrict is not None:
            rec.restrict(restrict)
        la = rec.log_alpha.copy()
        for frame in range(6):
            if frame:
                rec.predict()
                top = la.max(axis=1, keepdims=True)
                with np.errstate(divide="ignore", invalid="ignore"):
                    moved = np.log(np.einsum("ck,ckj->cj", np.exp(la - top), database.transmat_)) + top
                la = np.where(np.isfinite(top), moved, -np.inf)
                np.testing.assert_allclose(rec.log_alpha, la, rtol=1e-12, atol=1e-12)
            active = (la >= la.max(axis=1, keepdims=True) + np.log(1e-4)) & np.isfinite(la)
            assert np.array_equal(rec.active(), active)
            log_b = rng.normal(-20.0, 5.0, la.shape)
            norm = rec.update(log_b)
            la = la + np.where(active, log_b, log_b[active].min())
            finite = la[np.isfinite(la)]
            expect = np.log(np.sum(np.exp(finite - finite.max()))) + finite.max()
            assert norm == pytest.approx(expect, abs=1e-10)
            la = la - expect
            np.testing.assert_allclose(rec.log_alpha, la, rtol=1e-12, atol=1e-12)
            post = np.exp(la - la.max())
            np.testing.assert_allclose(rec.posterior, post / post.sum(), rtol=1e-12, atol=1e-300)
            np.testing.assert_allclose(rec.class_posterior, post.sum(axis=1) / post.sum(), rtol=1e-12, atol=1e-300)
            live = np.isfinite(la.max(axis=1))
            rows = np.exp(la[live] - la[live].max(axis=1, keepdims=True))
            np.testing.assert_allclose(rec.state_posterior[live], rows / rows.sum(axis=1, keepdims=True), rtol=1e-12,
                                       atol=1e-300)
            np.testing.assert_allclose(rec.state_posterior.sum(axis=1), 1.0)
            # A primitive outside the belief keeps its start distribution's shape.
            start = 0.95 * database.startprob_ + 0.05 / la.shape[1]
            np.testing.assert_allclose(rec.state_posterior[~live], start[~live], rtol=1e-12)
        if restrict is not None:
            assert rec.class_posterior[1] == 0.0 and not rec.active()[1].any()


def _random_image_distributions(rng, H, P):
    pix = rng.uniform(0, 100, (H, P, 2))
    flow = rng.normal(0, 30, (H, P, 2))
    A = rng.normal(0, 2, (H, P, 2, 2))
    B = rng.normal(0, 10, (H, P, 2, 2))
    visibility = np.where(rng.random((H, P)) < 0.7, rng.uniform(0.05, 1.0, (H, P)), 0.0)
    return ImageDistributions(pix, A @ np.swapaxes(A, -1, -2) + 4 * np.eye(2), flow,
                              B @ np.swapaxes(B, -1, -2) + 25 * np.eye(2), visibility)


def _gauss(x, mean, cov):
    d = x - mean
    return np.exp(-0.5 * d @ np.linalg.solve(cov, d)) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))


def _brute_force(flows, img, h, noise, fps, W, Hh, eps, iterations, smoothing, held):
    """The likelihood's rule written out with Python loops: per-flow log-likelihoods and responsibilities of
    hypothesis ``h`` (the position gate, visibility-proportional prior weights, EM on the weights of the points
    not held; held points share what the others leave in their prior proportions)."""
    vmax = 0.25 * max(W, Hh) * fps
    out_density = eps / (W * Hh * np.pi * vmax**2)
    M, P = len(flows), img.pix.shape[1]
    vis = img.visibility[h]
    dens = np.zeros((M, P))
    for m in range(M):
        for p in range(P):
            if vis[p] <= 0:
                continue
            cov = img.pix_cov[h, p] + noise**2 * np.eye(2)
            d = flows[m, :2] - img.pix[h, p]
            if d @ np.linalg.solve(cov, d) > 60.0:           # the gate
                continue
            dens[m, p] = (_gauss(flows[m, :2], img.pix[h, p], cov)
                          * _gauss(flows[m, 2:], img.flow[h, p], img.flow_cov[h, p] + 2 * (noise * fps) ** 2 * np.eye(2)))
    prior = vis / vis.sum()
    weight = prior.copy()

    def resp_of(weight):
        return np.array([[(1 - eps) * weight[p] * dens[m, p] / ((1 - eps) * weight @ dens[m] + out_density)
                          for p in range(P)] for m in range(M)])

    hold = held[h]
    for _ in range(iterations):
        r = resp_of(weight)
        weight = (r.sum(axis=0) + smoothing * prior) / (r.sum() + smoothing)
        if prior[hold].sum() > 0:
            weight[hold] = (1 - weight[~hold].sum()) * prior[hold] / prior[hold].sum()
    ll = np.array([np.log((1 - eps) * weight @ dens[m] + out_density) for m in range(M)])
    # The positions alone under the same weights: each point's position Gaussian where the joint had a density.
    positions = np.array([[_gauss(flows[m, :2], img.pix[h, p], img.pix_cov[h, p] + noise**2 * np.eye(2))
                           if dens[m, p] > 0 else 0.0 for p in range(P)] for m in range(M)])
    given = ll - np.array([np.log((1 - eps) * weight @ positions[m] + eps / (W * Hh)) for m in range(M)])
    return ll, resp_of(weight), given


@pytest.mark.parametrize("iterations, smoothing, share_held", [(0, 0.0, 0.0), (2, 10.0, 0.0), (3, 0.5, 0.0),
                                                                (2, 10.0, 0.5), (3, 0.5, 1.0)])
@pytest.mark.parametrize("M", [6, 8, 11])     # the kernels pad the flows to a multiple of 8
def test_flow_likelihood_and_responsibilities_match_brute_force(rng, iterations, smoothing, share_held, M):
    H, P = 3, 12
    img = _random_image_distributions(rng, H, P)
    # The open region: a grid of 10 px cells over [0, 80)^2 (the points lie in [0, 100)^2, so some are outside it
    # and never held), each cell open with chance ``share_held``; which points it holds, in numpy.
    mask = OpenMask(rng.random((8, 8)) < share_held, 10.0)
    cells = np.floor(img.pix / 10.0).astype(int)
    inside = (cells >= 0).all(axis=-1) & (cells < 8).all(axis=-1)
    held = inside & mask.open[np.clip(cells[..., 1], 0, 7), np.clip(cells[..., 0], 0, 7)]
    assert share_held == 0.0 or held.any()
    flows = np.concatenate([img.pix[0, :M] + rng.normal(0, 3, (M, 2)), rng.normal(0, 30, (M, 2))], axis=1)
    flows[-1, :2] = [5000.0, -300.0]                      # far from every point: an outlier
    noise, fps, W, Hh, eps = 1.5, 30.0, 640, 480, 0.05
    model = FlowModel(noise, fps, W, Hh, eps, weight_iterations=iterations, smoothing=smoothing)
    got = flow_log_likelihoods(flows, img, model, open_mask=mask)
    velocities = velocity_log_likelihoods(flows, img, model, open_mask=mask)
    # The kernels hold the flows and the points' means in float32: the reference takes the same rounded inputs
    # (a flow moved by half a float32 ulp, 4e-6 px here), so what is left is float32's arithmetic, its unit
    # round-off (6e-8) times the exponents' terms (below 200 in these draws), and the cut (e^-25 of the outlier
    # term): within 2e-5 nats per flow, and the responsibilities within 2e-5 of themselves.
    single = ImageDistributions(img.pix.astype(np.float32).astype(float), img.pix_cov,
                                img.flow.astype(np.float32).astype(float), img.flow_cov, img.visibility)
    rounded = flows.astype(np.float32).astype(float)
    for h in range(H):
        ll, resp, given = _brute_force(rounded, single, h, noise, fps, W, Hh, eps, iterations, smoothing, held)
        np.testing.assert_allclose(got[h], ll, rtol=0, atol=2e-5)
        np.testing.assert_allclose(velocities[h], given, rtol=0, atol=2e-5)
        one = ImageDistributions(*(getattr(img, k)[h:h + 1] for k in ("pix", "pix_cov", "flow", "flow_cov",
                                                                        "visibility")))
        r = responsibilities(flows, one, model, open_mask=mask)
        np.testing.assert_allclose(r, resp, rtol=2e-5, atol=1e-10)
        assert np.all(r[:, img.visibility[h] == 0] == 0)
    # With every point invisible, every flow is an outlier.
    none = ImageDistributions(img.pix, img.pix_cov, img.flow, img.flow_cov, np.zeros((H, P)))
    vmax = 0.25 * 640 * fps
    np.testing.assert_allclose(flow_log_likelihoods(flows, none, FlowModel(noise, fps, W, Hh, eps)),
                               np.log(eps / (W * Hh * np.pi * vmax**2)))
    # ... and its velocity is an outlier's, uniform over the disc of image speeds.
    np.testing.assert_allclose(velocity_log_likelihoods(flows, none, FlowModel(noise, fps, W, Hh, eps)),
                               -np.log(np.pi * vmax**2))


def test_the_kernels_elementary_functions_match_numpys():
    """The kernels' own (vectorising) exp and atan: relative error near machine precision over the range of
    normal doubles (exp; exactly zero below it and at minus infinity) and over [0, 1] (atan(t) / t)."""
    x = np.concatenate([np.linspace(-708.0, 709.0, 200001), [-0.0, 0.0, 1e-300, -1e-300]])
    out, work = np.empty_like(x), np.empty_like(x)
    exp_into(x, out, work)
    np.testing.assert_allclose(out, np.exp(x), rtol=1e-13)
    low = np.array([-708.5, -745.0, -1e5, -np.inf])
    out, work = np.empty_like(low), np.empty_like(low)
    exp_into(low, out, work)
    assert out.tolist() == [0.0, 0.0, 0.0, 0.0]
    t = np.concatenate([np.linspace(0.0, 1.0, 20001)[1:], [1e-300, 1e-9, np.sqrt(2) - 1]])
    np.testing.assert_allclose([atan_ratio(v) for v in t], np.arctan(t) / t, rtol=1e-14)
    assert atan_ratio(0.0) == 1.0
    x = np.concatenate([np.exp(np.linspace(-708.0, 709.0, 200001)), [LOG_MIN, 0.5, 1.0, 2.0, np.sqrt(2.0),
                                                                     np.nextafter(np.sqrt(2.0), 0.0), 1.7e308]])
    np.testing.assert_allclose([log_normal(v) for v in x], np.log(x), rtol=1e-15, atol=1e-300)
    assert log_normal(1.0) == 0.0


def test_the_float32_exponential_matches_numpys():
    """The density loops' float32 exp: within 3 float32 ulps (relative 3.6e-7) of the double exp over its range,
    and every result a normal float32 (no subnormal in the loops that use it)."""
    import numba

    @numba.njit
    def exp32(x):
        out = np.empty_like(x)
        for i in range(len(x)):
            m, s = exp32_parts(x[i])
            out[i] = m * s
        return out

    x = np.concatenate([np.linspace(EXP32_MIN, 88.0, 400001), [0.0, -0.0, np.log(2.0) / 2]]).astype(np.float32)
    got = exp32(x)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, np.exp(x.astype(float)), rtol=3 * np.finfo(np.float32).eps)
    assert got.min() >= np.finfo(np.float32).tiny


@pytest.mark.parametrize("log_out", [-33.0, -800.0])
def test_per_flow_log_likelihood_is_the_log_of_the_mixture(rng, log_out):
    """Each flow's log-likelihood ``log((1 - eps) total + eps U)``: by one vectorising log where the outlier term is
    a normal double (every camera in use), by the sum of the logs where it is not; both against numpy."""
    from harness.engine.likelihood import _per_flow

    total = np.concatenate([rng.random(40) * 1e-4, [0.0, 1e-300]])
    log_in = np.log1p(-0.05)
    out = np.empty(len(total))
    _per_flow(7, total, log_in, log_out, out)
    with np.errstate(divide="ignore"):
        np.testing.assert_allclose(out, np.logaddexp(log_in + np.log(total), log_out), rtol=1e-14)
    _per_flow(0, total, log_in, log_out, out)
    assert out.tolist() == [log_out] * len(total)


def test_tempering_counts_a_frame_as_at_most_n_eff_flows():
    per_flow = np.array([[-1.0, -2.0, -3.0, -4.0]])
    assert tempered(per_flow, 10.0)[0] == pytest.approx(-10.0)
    assert tempered(per_flow, 2.0)[0] == pytest.approx(-10.0 * 2 / 4)
    assert tempered(np.empty((3, 0)), 2.0).tolist() == [0.0, 0.0, 0.0]


def test_systematic_resampling_is_unbiased_and_low_variance(rng):
    w = rng.random(50) ** 3
    w /= w.sum()
    counts = np.zeros(50)
    for _ in range(400):
        idx = systematic_resample(w, rng)
        c = np.bincount(idx, minlength=50)
        # Systematic resampling keeps every count within one of its expectation.
        assert np.all(np.abs(c - 50 * w) < 1.0 + 1e-9)
        counts += c
    np.testing.assert_allclose(counts / 400, 50 * w, atol=0.06)
    assert effective_sample_size(np.ones(10)) == pytest.approx(10.0)
    assert effective_sample_size(np.eye(10)[0] + 1e-300) == pytest.approx(1.0)


def test_resampling_several_clouds_at_once_is_each_clouds_own(rng):
    """The compiled systematic resampling over segments: each cloud's indices are numpy's ``searchsorted`` of its
    cumulative shares (the last taken as one) at its own offset's pointers, and ``systematic_resample`` draws its
    offset from the generator as before."""
    from harness.engine.particle_filter import _resampled

    sizes, n = [7, 1, 30, 12], 9
    weights = rng.random(sum(sizes)) ** 4
    weights[7 + 1 + 3] = 0.0                       # a particle without weight is never drawn
    starts = np.concatenate([[0], np.cumsum(sizes)])
    offsets = rng.random(len(sizes))
    got = np.empty(len(sizes) * n, dtype=np.int64)
    _resampled(weights, starts, offsets, n, got)
    for j, (a, b) in enumerate(zip(starts[:-1], starts[1:])):
        cum = np.cumsum(weights[a:b] / weights[a:b].sum())
        cum[-1] = 1.0
        expected = a + np.searchsorted(cum, (offsets[j] + np.arange(n)) / n, side="right")
        np.testing.assert_array_equal(got[j * n:(j + 1) * n], expected)
    assert 7 + 1 + 3 not in got
    one, two = np.random.default_rng(4), np.random.default_rng(4)
    w = weights[:7] / weights[:7].sum()
    cum = np.cumsum(w)
    cum[-1] = 1.0
    np.testing.assert_array_equal(systematic_resample(w, one, 5),
                                  np.searchsorted(cum, (two.random() + np.arange(5)) / 5, side="right"))


def test_reweighting_several_clouds_at_once(rng):
    """``reweight_many``: each cloud's weights times its likelihoods, normalised, and the log of the weighted mean
    likelihood, as numpy computes them; a likelihood that is not finite weighs a particle out; one cloud given
    twice is refused (it would be weighed once, by the second)."""
    clouds = [ParticleCloud(np.zeros((k, 3)), np.tile([1.0, 0, 0, 0], (k, 1)), np.log(rng.dirichlet(np.ones(k))))
              for k in (5, 1, 12)]
    before = [c.log_weights.copy() for c in clouds]
    lls = [rng.normal(-40, 5, len(c)) for c in clouds]
    lls[2][3], lls[2][7] = -np.inf, np.nan
    norms = reweight_many(clouds, lls)
    for cloud, lw, ll, norm in zip(clouds, before, lls, norms):
        joint = lw + np.where(np.isfinite(ll), ll, -1e300)
        expected = np.log(np.sum(np.exp(joint - joint.max()))) + joint.max()
        assert norm == pytest.approx(expected, rel=1e-14)
        np.testing.assert_allclose(cloud.log_weights, joint - expected, rtol=1e-13)
        assert np.exp(cloud.log_weights).sum() == pytest.approx(1.0, rel=1e-13)
    assert np.exp(clouds[2].log_weights[[3, 7]]).tolist() == [0.0, 0.0]
    with pytest.raises(EngineError, match="twice"):
        reweight_many([clouds[0], clouds[0]], [lls[0], lls[0]])


def test_particle_cloud_estimate_and_motion_model(rng):
    q = upright_orientations(np.full(500, 0.3), camera_pitch(0.1))
    cloud = ParticleCloud(np.tile([0.1, 0.2, 4.0], (500, 1)) + rng.normal(0, 0.01, (500, 3)), q,
                          np.full(500, -np.log(500)))
    pos, quat = cloud.estimate()
    np.testing.assert_allclose(pos, [0.1, 0.2, 4.0], atol=0.003)
    assert geometry.angle_between(quat, q[0]) < 1e-9
    # One second of moving forward at 1 m/s in the base frame moves the poses along the body's x axis.
    moved, _ = motion_mean(cloud.positions, cloud.quats, np.array([1.0, 0, 0]), np.zeros(3), 1.0)
    np.testing.assert_allclose(moved - cloud.positions, np.tile(geometry.rotate(q[0], np.array([1.0, 0, 0])),
                                                                 (500, 1)), atol=1e-12)


@pytest.mark.parametrize("sizes", [(3, 10, 40, 200), (50, 50, 50, 50, 50)])
def test_settled_clouds_equal_the_mode_estimate_written_in_numpy(rng, sizes):
    """``settled`` against its definition in numpy, cloud by cloud: clouds of two orientation modes (one of more
    particles, the other of more weight), of ten or fewer particles (every particle a candidate centre) and of many, of different sizes and
    of one size (their candidates found together); the heavier mode's mean position and Markley mean, and the
    whole cloud's spread."""
    clouds = []
    for n in sizes:
        heavy, light = geometry.exp(rng.normal(0, 1.0, 3)), geometry.exp(rng.normal(0, 1.0, 3))
        k = (2 * n) // 3
        q = np.concatenate([geometry.multiply(geometry.exp(rng.normal(0, 0.1, (k, 3))), heavy),
                            geometry.multiply(geometry.exp(rng.normal(0, 0.1, (n - k, 3))), light)])
        q *= rng.choice([-1.0, 1.0], (n, 1))           # either sign is the same rotation
        lw = rng.normal(0, 1.0, n)
        lw[k:] += 3.0                                   # the mode of fewer particles holds more weight
        clouds.append(ParticleCloud(rng.normal(0, 1.0, (n, 3)) + [0, 0, 4], q, lw - np.log(np.exp(lw).sum())))
    positions, quats, spreads = settled(clouds)
    for cloud, pos, quat, spread in zip(clouds, positions, quats, spreads):
        w = cloud.weights
        centres = np.argpartition(w, -10)[-10:] if len(w) > 10 else np.arange(len(w))
        near = np.abs(cloud.quats[centres] @ cloud.quats.T) >= np.cos(np.deg2rad(22.5))
        near = near[np.argmax(near @ w)]
        wm = np.where(near, w, 0.0) / w[near].sum()
        np.testing.assert_allclose(pos, wm @ cloud.positions, rtol=1e-12)
        np.testing.assert_allclose(quat, geometry.weighted_mean(cloud.quats, wm), atol=1e-12)
        mean = w @ cloud.positions
        np.testing.assert_allclose(spread, np.sqrt(w @ (cloud.positions - mean) ** 2), rtol=1e-12)
        assert np.allclose(cloud.estimate()[1], quat, atol=1e-12)


def test_pose_mixture_density_matches_numpy_and_integrates_to_one(rng):
    """The proposal's pose mixture density against the formula written with numpy (the relative rotation's
    rotation vector in the noise frame), with an anisotropic noise frame, and its position-and-rotation
    integral by Monte Carlo: one."""
    K, N = 7, 300
    mean_pos = rng.normal(0, 0.1, (K, 3)) + [0.0, 0.0, 4.0]
    mean_quat = geometry.exp(rng.normal(0, 1.0, (K, 3)))
    log_w = np.log(rng.dirichlet(np.ones(K)))
    pos_std, rot_std = np.array([0.05, 0.08, 0.1]), np.array([0.1, 0.2, 0.05])
    frame = geometry.to_matrix(geometry.exp(np.array([0.3, -0.2, 0.5])))
    pos = mean_pos[rng.integers(0, K, N)] + rng.normal(0, 0.1, (N, 3))
    quat = geometry.multiply(geometry.exp(rng.normal(0, 0.2, (N, 3))), mean_quat[rng.integers(0, K, N)])
    dp = (pos[:, None] - mean_pos[None]) / pos_std
    dr = (geometry.log(geometry.multiply(quat[:, None], geometry.conjugate(mean_quat)[None])) @ frame) / rot_std
    terms = (log_w - 0.5 * (np.sum(dp**2, -1) + np.sum(dr**2, -1)) - np.log(pos_std).sum() - np.log(rot_std).sum()
             - 3 * np.log(2 * np.pi))
    expect = np.logaddexp.reduce(terms, axis=1)
    np.testing.assert_allclose(pose_mixture_log_density(pos, quat, mean_pos, mean_quat, log_w, pos_std, rot_std,
                                                        frame), expect, rtol=1e-12)
    # Importance sampling from a wide Gaussian around one component: the density integrates to its weight.
    one = np.zeros(1)
    n = 200000
    e = rng.normal(0, 3 * rot_std, (n, 3))
    x = mean_pos[0] + rng.normal(0, 3 * pos_std, (n, 3))
    q = geometry.multiply(geometry.exp(e @ frame.T), mean_quat[0])
    log_q = (-0.5 * np.sum(((x - mean_pos[0]) / (3 * pos_std)) ** 2 + (e / (3 * rot_std)) ** 2, -1)
             - np.log(3 * pos_std).sum() - np.log(3 * rot_std).sum() - 3 * np.log(2 * np.pi))
    density = pose_mixture_log_density(x, q, mean_pos[:1], mean_quat[:1], one, pos_std, rot_std, frame)
    assert np.mean(np.exp(density - log_q)) == pytest.approx(1.0, abs=0.02)


def test_many_clouds_proposed_at_once_move_each_by_its_own_velocity(rng):
    """``propose_many``: each cloud's new particles are its ancestors (drawn by weight) moved by its own base
    velocity, plus the process noise: their mean is the weighted mean of the moved ancestors and their spread
    the noise's (sample moments of 20000 particles)."""
    noise, dt, n = ProcessNoise(0.3, 0.2), 1 / 30, 20000
    clouds = [ParticleCloud(rng.normal(0, 0.02, (30, 3)) + [x, 0.0, 4.0], geometry.exp(rng.normal(0, 0.05, (30, 3))),
                            np.log(rng.dirichlet(np.ones(30)))) for x in (-1.0, 1.0)]
    v, w = np.array([[3.0, 0.0, 0.0], [0.0, 0.0, -3.0]]), np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.0]])
    moved = propose_many(clouds, n, noise, rng, base_linear=v, base_angular=w, dt=dt)
    for j, (cloud, new) in enumerate(zip(clouds, moved)):
        mean, _ = motion_mean(cloud.positions, cloud.quats, v[j], w[j], dt)
        expect = cloud.weights @ mean
        spread = np.sqrt(cloud.weights @ (mean - expect) ** 2 + noise.position**2 * dt)
        np.testing.assert_allclose(new.positions.mean(axis=0), expect, atol=4 * spread.max() / np.sqrt(n))
        np.testing.assert_allclose(new.positions.std(axis=0), spread, rtol=0.05)
        np.testing.assert_allclose(new.weights, 1.0 / n)


def test_mixture_proposal_is_importance_weighted(rng):
    """Particles proposed around a guide far from the motion model carry weights pi/q: the weighted cloud
    has the prior predictive's moments (checked against the bootstrap proposal), the unweighted one not."""
    n_parent = 40
    parents = ParticleCloud(rng.normal(0, 0.05, (n_parent, 3)) + [0.0, 0.0, 4.0],
                            geometry.exp(rng.normal(0, 0.1, (n_parent, 3))), np.log(rng.dirichlet(np.ones(n_parent))))
    noise = ProcessNoise(0.15, 0.3)
    guide = (np.array([0.3, 0.0, 4.0]), geometry.exp(np.array([0.0, 0.2, 0.0])))
    still = dict(base_linear=np.zeros(3), base_angular=np.zeros(3), dt=1 / 30)
    bootstrap = propose(parents, 40000, noise, rng, **still)
    guided = propose(parents, 40000, noise, rng, **still, guide=guide, guide_fraction=0.5,
                     guide_std=(np.full(3, 0.1), 0.05))
    mean_b = bootstrap.weights @ bootstrap.positions
    mean_g = guided.weights @ guided.positions
    np.testing.assert_allclose(mean_g, mean_b, atol=0.005)
    assert guided.positions.mean(axis=0)[0] - mean_b[0] > 0.1         # unweighted, the guide would pull it
    var_b = bootstrap.weights @ (bootstrap.positions - mean_b) ** 2
    var_g = guided.weights @ (guided.positions - mean_g) ** 2
    np.testing.assert_allclose(var_g, var_b, rtol=0.1)
    np.testing.assert_allclose(guided.weights.sum(), 1.0)


def _posed_scene(body, rng):
    """A camera, 150 model points, a random posture and a base pose 4 m away; ``camera_points(angles, rot, pos)``:
    the model points in the camera frame (the scene's base pose by default)."""
    intr = Intrinsics.from_fov(45.0, 640, 480)
    points = sample_surface(body, 150, rng)
    theta = body.random_angles(rng, scale=0.3)
    rot = geometry.to_matrix(upright_orientations(np.array([0.8]), camera_pitch(0.15)))[0]
    pos = np.array([0.1, 0.2, 4.0])

    def camera_points(angles, rot=rot, pos=pos):
        q = body.qpos(angles, base_pos=np.zeros(3), base_quat=np.array([1.0, 0, 0, 0]))
        return forward_points(body, q, points.body, points.local, frame="base") @ rot.T + pos

    return intr, points, theta, rot, pos, camera_points


def test_refinement_recovers_a_perturbed_pose(body):
    """Noiseless flows at known model points: Gauss-Newton from a perturbed start lands on the truth."""
    rng = np.random.default_rng(4)
    intr, points, theta, rot, pos, camera_points = _posed_scene(body, rng)
    flows = np.concatenate([project(intr, camera_points(theta)), np.zeros((150, 2))], axis=1)
    resp = np.eye(150)
    start = np.clip(theta + rng.normal(0, np.deg2rad(5), 50), body.lower, body.upper)
    prior = Prior(start, np.full(50, 1.0), pos + 0.05, np.full(3, 1.0), rot, 1.0)
    got = refine_pose(body, points, intr, flows, resp, prior, noise_px=0.5, spread=0.0, iterations=8)
    pos_r = got.position
    assert np.abs(project(intr, camera_points(got.angles, got.rotation, pos_r)) - flows[:, :2]).max() < 0.05
    assert np.linalg.norm(pos_r - pos) < 0.01
    assert patch_std(body, 150) == pytest.approx(patch_std(body, 600) * 2, rel=1e-12)


def test_the_no_database_ablation_fits_the_flow_positions(body):
    """The ablation scores positions alone (its flows' velocities are ignored, here nonsense) and follows a
    posture that moves away from its zero start over frames: at the end the model points it fits are nearer the
    truth than the zero posture's, in the image and in 3D. (A version whose responsibilities were all zero never
    moved its angles: both ratios were 1.)"""
    rng = np.random.default_rng(5)
    intr, points, theta, rot, pos, camera_points = _posed_scene(body, rng)
    T = 15
    path = [np.clip(theta * (t + 1) / T, body.lower, body.upper) for t in range(T)]
    flows = [np.concatenate([project(intr, camera_points(a)), rng.normal(0, 300, (150, 2))], axis=1) for a in path]
    got = fit_without_database(body, points, intr, flows, np.tile(pos, (T, 1)),
                               np.tile(geometry.from_matrix(rot), (T, 1)), noise_px=1.0, spread=0.0)
    truth, fitted, zero = camera_points(path[-1]), camera_points(got[-1]), camera_points(np.zeros(50))
    image = np.abs(project(intr, fitted) - project(intr, truth)).mean() / np.abs(project(intr, zero)
                                                                                 - project(intr, truth)).mean()
    space = np.linalg.norm(fitted - truth, axis=1).mean() / np.linalg.norm(zero - truth, axis=1).mean()
    assert image < 0.5          # at least half the way in the image, a third in 3D (measured: 0.37 and 0.46)
    assert space < 2 / 3


def _refine_in_numpy(body, points, intr, flows, resp, prior, *, noise_px, spread, iterations, start, fix_pose,
                     damping=1e-3):
    """``refine_pose`` as it was written in numpy before the compiled steps (the reference)."""
    angles = np.clip(np.asarray(start.angles, dtype=float), body.lower, body.upper)
    pos, rot = np.array(start.position, dtype=float), np.array(start.rotation, dtype=float)
    mass = resp.sum(axis=0)
    used = mass > 1e-3
    target = (resp[:, used].T @ flows[:, :2]) / mass[used, None]
    sub = points.subset(np.flatnonzero(used))
    prior_prec = np.concatenate([1.0 / prior.angle_std**2, 1.0 / prior.position_std**2,
                                 np.full(3, 1.0 / prior.rotation_std**2)])
    for _ in range(iterations):
        x, jac = forward_points_and_jacobians(body, body.qpos(angles, np.zeros(3), [1.0, 0, 0, 0]), sub.body,
                                              sub.local, frame="base")
        X = x @ rot.T + pos
        if np.any(X[:, 2] < 0.05):
            break
        P = projection_jacobian(intr, X)
        w = mass[used] / (noise_px**2 + (intr.fy * spread / X[:, 2]) ** 2)
        skew = np.zeros((len(x), 3, 3))
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -x[:, 2], x[:, 1], -x[:, 0]
        skew -= np.swapaxes(skew, 1, 2)
        G = np.concatenate([P @ rot @ jac, P, -P @ rot @ skew], axis=2)
        Gw = (G * np.sqrt(w)[:, None, None]).reshape(-1, 56)
        A = Gw.T @ Gw
        b = Gw.T @ ((target - project(intr, X)) * np.sqrt(w)[:, None]).ravel()
        offset = np.concatenate([angles - prior.angles, pos - prior.position,
                                 geometry.log(geometry.from_matrix(prior.rotation.T @ rot))])
        A[np.diag_indices(56)] = (A[np.diag_indices(56)] + prior_prec) * (1.0 + damping)
        b -= prior_prec * offset
        free = slice(0, 50) if fix_pose else slice(0, 56)
        step = np.zeros(56)
        step[free] = np.linalg.solve(A[free, free], b[free])
        angles = np.clip(angles + step[:50], body.lower, body.upper)
        pos = pos + step[50:53]
        rot = rot @ geometry.to_matrix(geometry.exp(step[53:]))
    return angles, pos, rot


@pytest.mark.parametrize("fix_pose, iterations, spread, depth", [(False, 3, 0.02, 4.0), (True, 2, 0.02, 4.0),
                                                                 (False, 1, 0.0, 4.0), (False, 3, 0.02, 0.5)])
def test_compiled_refinement_equals_the_numpy_steps(body, fix_pose, iterations, spread, depth):
    """``refine_pose``'s compiled steps (normal equations summed per body over each chain's columns, the
    rotation's offset and step without quaternion round trips) against the numpy steps, on soft assignments of
    noisy flows, with the pose free or fixed; at 0.5 m the body reaches nearer the camera than ``MIN_DEPTH``
    and the steps stop where the numpy ones stop."""
    rng = np.random.default_rng(5)
    intr = Intrinsics.from_fov(45.0, 640, 480)
    points = sample_surface(body, 150, rng)
    theta = body.random_angles(rng, scale=0.3)
    rot = geometry.to_matrix(upright_orientations(np.array([2.0]), camera_pitch(0.2)))[0]
    pos = np.array([0.2, -0.1, depth])
    X = forward_points(body, body.qpos(theta, np.zeros(3), [1.0, 0, 0, 0]), points.body, points.local,
                       frame="base") @ rot.T + pos
    source = rng.choice(150, 60, replace=False)
    flows = np.concatenate([project(intr, X[source]) + rng.normal(0, 2.0, (60, 2)), rng.normal(0, 50, (60, 2))], axis=1)
    resp = np.zeros((60, 150))
    for m, p in enumerate(source):          # most of each flow on its point, the rest on two others
        resp[m, p] = rng.uniform(0.5, 0.9)
        resp[m, rng.choice(150, 2)] += (0.95 - resp[m, p]) / 2
    turn = geometry.to_matrix(geometry.exp(rng.normal(0, 0.05, 3)))
    start = Recovery(np.clip(theta + rng.normal(0, 0.1, 50), body.lower, body.upper), pos + rng.normal(0, 0.05, 3),
                     rot @ turn)
    prior = Prior(theta + rng.normal(0, 0.1, 50), rng.uniform(0.05, 0.5, 50), pos, np.full(3, 0.25), rot, 0.3)
    got = refine_pose(body, points, intr, flows, resp, prior, noise_px=1.0, spread=spread, iterations=iterations,
                      start=start, fix_pose=fix_pose)
    angles, position, rotation = _refine_in_numpy(body, points, intr, flows, resp, prior, noise_px=1.0, spread=spread,
                                                  iterations=iterations, start=start, fix_pose=fix_pose)
    assert not np.allclose(got.angles, start.angles) or depth < 1.0       # the steps moved, unless stopped
    np.testing.assert_allclose(got.angles, angles, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.position, position, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.rotation, rotation, rtol=1e-9, atol=1e-12)


def test_compiled_rotation_vector_and_matrix_match_geometry(rng):
    """The compiled steps' rotation log (Shepperd's quaternion, each of its four branches; also ``Recovery.qpos``'s
    quaternion) and exp against ``geometry``: random rotations, half turns about each axis and nearby, and steps
    down to 1e-10 rad."""
    from harness.engine.recovery import _rotation_matrix, _rotation_vector

    vectors = [rng.normal(0, 1, 3) for _ in range(20)] + [rng.normal(0, 1e-10, 3), np.zeros(3)]
    for axis in np.eye(3):
        vectors += [np.pi * axis, (np.pi - 1e-6) * axis + rng.normal(0, 1e-3, 3)]
    for v in vectors:
        q = geometry.exp(v)
        out, mat = np.empty(3), np.empty((3, 3))
        _rotation_matrix(v, mat)
        np.testing.assert_allclose(mat, geometry.to_matrix(q), rtol=0, atol=1e-14)
        _rotation_vector(mat, out)
        quat = Recovery(np.zeros(50), np.zeros(3), mat).qpos[3:7]
        reference = geometry.from_matrix(mat)          # w >= 0 too; a half turn (w = 0) has two signs
        np.testing.assert_allclose(quat * np.sign(quat @ reference), reference, rtol=0, atol=1e-14)
        assert quat[0] >= 0
        expected = geometry.log(geometry.from_matrix(mat))
        if np.linalg.norm(expected) > np.pi - 1e-9:          # a half turn: v and -v are the same rotation
            expected = expected * np.sign(expected @ out)
        np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)



def test_robust_emissions_against_per_feature_densities(database):
    """``log_emissions`` with an outlier share is the sum over the measured features of
    ``log((1 - eps) N(f; m, v) + eps / span)``, computed here feature by feature with scipy; the span is the
    lowest ``mean - 3 sd`` to the highest ``mean + 3 sd``; unmeasured features do not count."""
    from scipy.stats import norm
    db = database
    f = db.means_[1, 3] + np.random.default_rng(2).normal(0, 1, (2, 106)) * np.sqrt(db.covars_[1, 3]) * 4
    measured = np.random.default_rng(3).random(106) < 0.7
    sd = np.sqrt(db.covars_)
    span = (db.means_ + 3 * sd).max(axis=(0, 1)) - (db.means_ - 3 * sd).min(axis=(0, 1))
    np.testing.assert_allclose(db.feature_span(), span)
    eps = 0.05
    got = db.log_emissions(f, outlier=eps, measured=measured)
    for t in range(2):
        for c, k in [(0, 0), (1, 3), (2, 7)]:
            dens = (1 - eps) * norm.pdf(f[t], db.means_[c, k], sd[c, k]) + eps / span
            assert got[t, c, k] == pytest.approx(np.log(dens[measured]).sum(), rel=1e-10)
    plain = db.log_emissions(f)
    assert plain[0, 1, 3] == pytest.approx(norm.logpdf(f[0], db.means_[1, 3], sd[1, 3]).sum(), rel=1e-10)
    moved = f.copy()
    moved[:, ~measured] += 10.0                                         # unmeasured: no effect
    np.testing.assert_allclose(db.log_emissions(moved, outlier=eps, measured=measured), got)
    with pytest.raises(EngineError, match="outlier"):
        db.log_emissions(f, outlier=1.0)
    with pytest.raises(EngineError, match="measured"):
        db.log_emissions(f, measured=measured[:50])


def test_robust_emissions_kernel_against_numpy_over_every_state(database):
    """The compiled sum (``_robust_log_densities``: its own exponential and logarithm) equals numpy's
    ``logaddexp`` of the Gaussian and the outlier term, summed over the measured features, for every frame, class
    and state, near the states and far from them (where the outlier term takes over)."""
    db = database
    rng = np.random.default_rng(5)
    f = db.means_[2, 1] + rng.normal(0, 1, (7, 106)) * np.sqrt(db.covars_[2, 1]) * np.array([[1], [3], [10]] * 2
                                                                                           + [[100]])
    for measured in (None, rng.random(106) < 0.6):
        keep = np.ones(106, dtype=bool) if measured is None else measured
        var = db.covars_[None][..., keep]
        d = f[:, None, None, keep] - db.means_[None][..., keep]
        gauss = -0.5 * (d * d / var + np.log(2 * np.pi * var))
        for eps in (0.05, 0.3):
            want = np.logaddexp(np.log1p(-eps) + gauss, np.log(eps) - np.log(db.feature_span()[keep])).sum(axis=-1)
            # A sum of ~100 terms, each rounded: about 100 unit round-offs of the sum, within 1e-13 with margin.
            np.testing.assert_allclose(db.log_emissions(f, outlier=eps, measured=measured), want, rtol=1e-13,
                                       atol=1e-11)
    gap = f.copy()
    gap[2, 5] = np.nan                       # a feature not measured at one frame, not masked: NaN, as numpy
    got = db.log_emissions(gap, outlier=0.05)
    assert np.isnan(got[2]).all() and np.isfinite(np.delete(got, 2, axis=0)).all()


def test_one_far_feature_does_not_hand_the_answer_to_the_broad_class(database):
    """The catch-all the outlier share removes: a performance that matches class A's state in every feature
    but one, held 40 sd away, goes to a class B whose Gaussians are four times broader under the plain
    Gaussian emissions, and to A with the outlier share."""
    db = MotionDatabase(n_states=2, mirrored=False)
    mean = np.zeros(106)
    db.classes_ = np.array(["a", "b"])
    db.means_ = np.stack([np.tile(mean, (2, 1)), np.tile(mean + 0.3, (2, 1))])
    db.covars_ = np.stack([np.full((2, 106), 0.01), np.full((2, 106), 0.16)])
    db.transmat_ = np.tile([[0.5, 0.5], [0.0, 1.0]], (2, 1, 1))
    db.startprob_ = np.tile([1.0, 0.0], (2, 1))
    db.fps_, db.cyclic_ = 30.0, np.zeros(2, dtype=bool)
    f = np.tile(mean, (5, 1))
    f[:, 7] = 40 * 0.1
    assert db.classes_[recognize_features(db, f, outlier=0.0)[-1].argmax()] == "b"
    assert db.classes_[recognize_features(db, f)[-1].argmax()] == "a"


def test_database_rejects_bad_input(database, body, tmp_path):
    with pytest.raises(EngineError, match="no training motions"):
        MotionDatabase().fit([])
    with pytest.raises(EngineError, match="shorter than"):
        MotionDatabase(n_states=200).fit(synthetic_demos(body, "wave", 2, np.random.default_rng(0)))
    bad = MotionDatabase(n_states=8)
    bad.classes_, bad.means_, bad.covars_ = database.classes_, database.means_[:, :, :50], database.covars_
    bad.transmat_, bad.startprob_, bad.fps_ = database.transmat_, database.startprob_, 30.0
    with pytest.raises(EngineError, match=r"database means has shape"):
        bad.validate()
    with pytest.raises(EngineError, match="not trained"):
        MotionDatabase().log_emissions(np.zeros((3, 106)))
    (tmp_path / "x.npz").write_bytes(b"nonsense")
    with pytest.raises(EngineError, match="not a motion database"):
        MotionDatabase.load(tmp_path / "x.npz")


def test_engine_imports_nothing_from_the_simulator():
    """The wall: the engine package reads observations, intrinsics, the body model and the database only."""
    root = pathlib.Path(__file__).resolve().parents[1] / "harness" / "engine"
    for path in root.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                assert not name.startswith(("harness.scene", "harness.evaluation", "mujoco")), (path.name, name)
