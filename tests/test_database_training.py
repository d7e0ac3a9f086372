"""The database's training rules (issue 24) against independent computations: the floored, masked Baum-Welch
(``engine.training``) and the human variance floor (``engine.variance_floor``)."""

import numpy as np
import pytest
from hmmlearn.hmm import GaussianHMM

from engine_fixtures import synthetic_demos
from harness.engine import MotionDatabase, motion_features
from harness.engine.features import N_FEATURES, measured_features, mirror_variances
from harness.engine.training import fit_primitive, left_to_right, masked_moments, state_posteriors
from harness.engine.variance_floor import (FLOOR_SCALE, HUMAN_FLOOR_PATH, group_floor, pooled_floor,
                                           read_human_floor, residual_variance, save_human_floor, variance_floor)
from harness.errors import EngineError
from harness.motion import Motion

K = 6


def _sequences(rng, n=4, T=40, F=5):
    """Piecewise-constant means along time plus noise: a left-to-right structure for K states."""
    out = []
    for _ in range(n):
        level = np.repeat(rng.normal(0.0, 3.0, (K, F)), T // K + 1, axis=0)[:T]
        out.append(level + rng.normal(0.0, 0.5, (T, F)))
    return out


def _hmmlearn_fit(x, lengths, floor, n_iter):
    """hmmlearn's own Baum-Welch from the database's initialisation (segment means and variances)."""
    seg = np.concatenate([np.minimum((np.arange(n) * K) // n, K - 1) for n in lengths])
    hmm = GaussianHMM(n_components=K, covariance_type="diag", n_iter=n_iter, init_params="", params="stmc",
                      min_covar=1e-6, implementation="log")
    hmm.startprob_, hmm.transmat_ = np.eye(K)[0], left_to_right(K, np.mean(lengths) / K, False)
    hmm.means_ = np.stack([x[seg == k].mean(0) for k in range(K)])
    hmm.covars_ = np.stack([np.maximum(x[seg == k].var(0), floor) for k in range(K)])
    return hmm.fit(x, lengths)


def test_with_every_feature_measured_and_a_negligible_floor_it_is_hmmlearns_baum_welch():
    rng = np.random.default_rng(0)
    seqs = _sequences(rng)
    floor = np.full(seqs[0].shape[1], 1e-9)
    means, covars, trans, start = fit_primitive(seqs, [np.ones_like(s, dtype=bool) for s in seqs], n_states=K,
                                                cyclic=False, floor=floor, n_iter=5,
                                                population=(np.zeros(5), np.ones(5)))
    ref = _hmmlearn_fit(np.concatenate(seqs), [len(s) for s in seqs], floor, 5)
    np.testing.assert_allclose(means, ref.means_, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(covars, np.diagonal(ref.covars_, axis1=1, axis2=2), rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(trans, ref.transmat_, atol=1e-8)


def test_every_m_step_keeps_the_floor_and_em_never_lowers_the_likelihood():
    rng = np.random.default_rng(1)
    seqs = _sequences(rng)
    floor = np.array([4.0, 1e-6, 1e-6, 1e-6, 1e-6])          # feature 0 far above its within-state spread (0.25)
    masks = [np.ones_like(s, dtype=bool) for s in seqs]
    fits = [fit_primitive(seqs, masks, n_states=K, cyclic=False, floor=floor, n_iter=n,
                          population=(np.zeros(5), np.ones(5))) for n in (0, 2, 8)]
    x, lengths = np.concatenate(seqs), [len(s) for s in seqs]
    scores = []
    for means, covars, trans, start in fits:
        assert np.all(covars >= floor) and np.any(np.isclose(covars[:, 0], 4.0))      # the floor binds
        hmm = GaussianHMM(n_components=K, covariance_type="diag")
        hmm.n_features, hmm.startprob_, hmm.transmat_, hmm.means_, hmm.covars_ = 5, start, trans, means, covars
        scores.append(hmm.score(x, lengths))
    assert scores[0] <= scores[1] + 1e-6 <= scores[2] + 2e-6


def test_a_feature_a_demonstration_does_not_measure_neither_trains_nor_aligns():
    """State posteriors ignore an unmeasured feature's values; a class that never measures a feature keeps the
    population's Gaussian for it; a demonstration that does not measure it leaves its estimate alone."""
    rng = np.random.default_rng(2)
    seqs = _sequences(rng)
    means, covars, trans, start = fit_primitive(seqs, [np.ones_like(s, dtype=bool) for s in seqs], n_states=K,
                                                cyclic=False, floor=np.full(5, 1e-6), n_iter=3,
                                                population=(np.zeros(5), np.ones(5)))
    mask = np.array([True, True, False, True, True])
    garbled = seqs[0].copy()
    garbled[:, 2] = rng.normal(0.0, 50.0, len(garbled))
    np.testing.assert_allclose(state_posteriors(means, covars, trans, start, garbled, mask),
                               state_posteriors(means, covars, trans, start, seqs[0], mask), atol=1e-12)
    # Feature 2 measured by no demonstration: the population's mean and variance (floored), in every state.
    masks = [np.broadcast_to(mask, s.shape) for s in seqs]
    population = (np.full(5, 7.0), np.full(5, 3.0))
    m2, c2, _, _ = fit_primitive(seqs, masks, n_states=K, cyclic=False, floor=np.full(5, 1e-6), n_iter=3,
                                 population=population)
    np.testing.assert_allclose(m2[:, 2], 7.0)
    np.testing.assert_allclose(c2[:, 2], 3.0)
    # One demonstration's feature 2 replaced by a constant it does not measure: the fit of the others' frames,
    # whatever the constant.
    masks = [np.ones_like(s, dtype=bool) for s in seqs]
    masks[1] = np.broadcast_to(mask, seqs[1].shape)
    fits = []
    for constant in (0.0, 100.0):
        held = [s.copy() for s in seqs]
        held[1][:, 2] = constant
        fits.append(fit_primitive(held, masks, n_states=K, cyclic=False, floor=np.full(5, 1e-6), n_iter=3,
                                  population=population))
    np.testing.assert_allclose(fits[0][0], fits[1][0], atol=1e-9)
    np.testing.assert_allclose(fits[0][1], fits[1][1], atol=1e-9)


def test_masked_moments_against_numpy():
    rng = np.random.default_rng(3)
    x, mask, w = rng.normal(size=(30, 4)), rng.random((30, 4)) > 0.3, rng.random((2, 30))
    mask[:, 3] = False
    mean, var, tot = masked_moments(x, mask.astype(float), w, (np.full((2, 4), -1.0), np.full((2, 4), 9.0)))
    for k in range(2):
        for f in range(3):
            sel = mask[:, f]
            m = np.average(x[sel, f], weights=w[k, sel])
            assert mean[k, f] == pytest.approx(m) and tot[k, f] == pytest.approx(w[k, sel].sum())
            assert var[k, f] == pytest.approx(np.average((x[sel, f] - m) ** 2, weights=w[k, sel]))
    assert np.all(mean[:, 3] == -1.0) and np.all(var[:, 3] == 9.0)


def test_the_database_learns_an_unmeasured_joint_from_the_other_classes(body):
    """A class whose captures hold a joint at zero (a BVH hand) takes the other classes' frames of it."""
    rng = np.random.default_rng(4)
    j = body.angle_index("rwrist_z")
    squats = synthetic_demos(body, "squat", 3, rng)
    waves = []
    for m in synthetic_demos(body, "wave", 3, rng):
        q = np.array(m.qpos)
        q[:, 7 + j] = 0.6 + 0.2 * np.sin(np.arange(len(q)) / 5.0)
        waves.append(m.replace(qpos=q))
    held = []
    for m in squats:
        q = np.array(m.qpos)
        q[:, 7 + j] = 0.0                                        # not measured
        held.append(m.replace(qpos=q))
    assert not held[0].measured_joints[j] and waves[0].measured_joints[j]
    db = MotionDatabase(n_states=4, n_iter=3, mirrored=False).fit(held + waves)
    frames = np.concatenate([motion_features(m)[:, j] for m in waves])
    squat = list(db.classes_).index("squat")
    np.testing.assert_allclose(db.means_[squat, :, j], frames.mean(), atol=1e-9)
    np.testing.assert_allclose(db.covars_[squat, :, j], max(frames.var(), db.floor[j]), rtol=1e-9)
    assert np.all(measured_features(waves[0])[[j, 50 + j]]) and not np.any(measured_features(held[0])[[j, 50 + j]])


def test_a_chain_per_source_is_each_sources_own_fit_and_an_absent_source_is_never_entered(body, tmp_path):
    """``by_source``: the squats of two sources (``studio`` with a bias on one joint) and the waves of one. Each
    squat chain is the one-source fit of its own demonstrations (exactly the chain a database of that source alone
    learns), the waves' missing source is a chain the recursion never enters, forwards or backwards, and the file
    keeps the layout."""
    from harness.engine.reverse import reversed_database

    rng = np.random.default_rng(5)
    j = body.angle_index("lfemur_y")
    squats = [m.replace(source="procedural") for m in synthetic_demos(body, "squat", 3, rng)]
    studio = []
    for m in synthetic_demos(body, "squat", 3, rng):
        q = np.array(m.qpos)
        q[:, 7 + j] += 0.4
        studio.append(m.replace(qpos=q, source="studio"))
    waves = [m.replace(source="procedural") for m in synthetic_demos(body, "wave", 3, rng)]
    db = MotionDatabase(n_states=4, n_iter=3, mirrored=False, by_source=True).fit(squats + studio + waves)
    assert db.sources_ == ("procedural", "studio") and db.means_.shape == (2, 8, N_FEATURES) and db.n_chains == 2
    squat, wave = list(db.classes_).index("squat"), list(db.classes_).index("wave")
    alone = MotionDatabase(n_states=4, n_iter=3, mirrored=False).fit(studio)
    np.testing.assert_allclose(db.means_[squat, 4:], alone.means_[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(db.startprob_[squat].reshape(2, 4).sum(axis=1), [0.5, 0.5])
    np.testing.assert_array_equal(db.startprob_[wave, 4:], 0.0)              # no studio wave
    assert db.startprob_[wave, :4].sum() == pytest.approx(1.0)
    assert not np.any(db.transmat_[:, :4, 4:]) and not np.any(db.transmat_[:, 4:, :4])
    np.testing.assert_array_equal(reversed_database(db).startprob_[wave, 4:], 0.0)
    db.save(tmp_path / "db.npz")
    back = MotionDatabase.load(tmp_path / "db.npz")
    assert back.sources_ == db.sources_ and back.n_chains == 2 and np.array_equal(back.means_, db.means_)


class _OneState:
    """A one-state, one-class database: the state posterior is 1 in every frame."""

    def __init__(self, mean, var):
        self.classes_ = np.array(["c"])
        self.means_, self.covars_ = mean[None, None], var[None, None]
        self.transmat_, self.startprob_ = np.ones((1, 1, 1)), np.ones((1, 1))


def test_residual_variance_is_the_mean_squared_deviation_about_the_state_means():
    rng = np.random.default_rng(5)
    y, mean = rng.normal(size=(25, N_FEATURES)), rng.normal(size=N_FEATURES)
    db = _OneState(mean, np.ones(N_FEATURES))
    np.testing.assert_allclose(residual_variance(db, "c", y), ((y - mean) ** 2).mean(0), rtol=1e-12)
    mask = np.ones(N_FEATURES, dtype=bool)
    mask[3] = False
    r = residual_variance(db, "c", y, mask)
    assert np.isnan(r[3]) and np.allclose(np.delete(r, 3), np.delete(((y - mean) ** 2).mean(0), 3))


def test_pooled_floor_is_the_median_over_those_that_measure_it_and_mirror_symmetric(tmp_path):
    rng = np.random.default_rng(6)
    r = rng.random((7, N_FEATURES))
    r[:3, 10] = np.nan
    r[:, 20] = np.nan
    pooled = pooled_floor(list(r))
    np.testing.assert_allclose(pooled, mirror_variances(pooled))
    expect = np.array([np.median(c[~np.isnan(c)]) if (~np.isnan(c)).any() else 0.0 for c in r.T])
    np.testing.assert_allclose(pooled, 0.5 * (expect + mirror_variances(expect)))
    save_human_floor(tmp_path / "f.json", pooled, {"test": True})
    np.testing.assert_allclose(read_human_floor(tmp_path / "f.json"), pooled, rtol=1e-5)
    (tmp_path / "bad.json").write_text('{"variance": [1, 2]}')
    with pytest.raises(EngineError, match="106"):
        read_human_floor(tmp_path / "bad.json")
    with pytest.raises(EngineError, match="no held-out"):
        pooled_floor([])


def test_the_default_floor_is_the_scaled_human_floor_never_below_the_group_floor():
    table = read_human_floor(HUMAN_FLOOR_PATH)
    np.testing.assert_allclose(variance_floor(), np.maximum(group_floor(), FLOOR_SCALE * table))
    assert np.all(variance_floor() >= group_floor())
    assert MotionDatabase().floor is variance_floor()
    with pytest.raises(EngineError, match="floor"):
        MotionDatabase(floor=np.zeros(N_FEATURES))


def test_measured_joints_are_those_that_move(body):
    q = np.tile(np.r_[0.0, 0.0, 0.95, 1.0, 0.0, 0.0, 0.0, np.zeros(50)], (10, 1))
    q[:, 7 + 4] = np.deg2rad(np.linspace(0.0, 0.4, 10))         # moves less than MEASURED_RANGE_DEG
    q[:, 7 + 5] = np.deg2rad(np.linspace(0.0, 2.0, 10))
    measured = Motion(q, 30.0, "x").measured_joints
    assert measured.sum() == 1 and measured[5]


def _brute_force_baum_welch(seqs, masks, start, trans, means, covars, floor, n_iter, floor_each_step=True):
    """Baum-Welch by enumerating every state path (no forward-backward recursion, no hmmlearn): the masked
    emission is the product over each frame's measured features, the M-step's sums run over the frames that
    measure each feature, and the variance is ``max(estimate, floor)`` (hmmlearn's estimate: its default
    ``covars_prior`` 0.01 over the occupancy). ``floor_each_step=False``: the floor applied after EM only."""
    from itertools import product
    K = len(start)
    for _ in range(n_iter):
        post_sum, obs, obs2 = np.zeros(means.shape), np.zeros(means.shape), np.zeros(means.shape)
        xi, first = np.zeros((K, K)), np.zeros(K)
        for y, mk in zip(seqs, masks):
            T = len(y)
            logpdf = -0.5 * mk[:, None, :] * ((y[:, None, :] - means[None]) ** 2 / covars[None]
                                              + np.log(2.0 * np.pi * covars[None]))
            emit = logpdf.sum(-1)                                                        # (T, K)
            gamma, pair, total = np.zeros((T, K)), np.zeros((K, K)), 0.0
            for path in product(range(K), repeat=T):
                p = start[path[0]] * np.prod([trans[a, b] for a, b in zip(path[:-1], path[1:])])
                if p == 0.0:
                    continue
                p *= np.exp(sum(emit[t, s] for t, s in enumerate(path)))
                total += p
                gamma[np.arange(T), path] += p
                for a, b in zip(path[:-1], path[1:]):
                    pair[a, b] += p
            gamma, pair = gamma / total, pair / total
            first += gamma[0]
            xi += pair
            post_sum += gamma.T @ mk
            obs += gamma.T @ (mk * y)
            obs2 += gamma.T @ (mk * y * y)
        start = first / first.sum()
        trans = xi / xi.sum(axis=1, keepdims=True)
        means = obs / post_sum
        var = (0.01 + obs2 - means**2 * post_sum) / post_sum
        covars = np.maximum(var, floor) if floor_each_step else var
    return means, np.maximum(covars, floor), trans, start


def test_masked_floored_baum_welch_against_enumerating_every_path():
    """Two EM steps of ``fit_primitive`` equal Baum-Welch computed by brute force over all state paths, with
    some frames not measuring some features and a floor that binds; the floor kept only after EM, or the
    unmeasured frames counted, give other answers (so the comparison can tell the rules apart)."""
    rng = np.random.default_rng(7)
    K, F, T = 3, 3, 7
    seqs = []
    for _ in range(3):
        level = np.repeat(rng.normal(0.0, 2.0, (K, F)), T // K + 1, axis=0)[:T]
        seqs.append(level + rng.normal(0.0, 0.4, (T, F)))
    masks = [np.ones((T, F), dtype=bool) for _ in seqs]
    masks[1][:, 2] = False                      # a demonstration that never measures feature 2
    masks[2][[1, 4], 0] = False                 # and two frames that do not measure feature 0
    seqs[1][:, 2] = 40.0                        # what it holds there must not matter
    floor = np.array([0.3, 1e-3, 1e-3])        # binds for feature 0 (within-state spread about 0.16)
    population = (np.zeros(F), np.ones(F))
    got = fit_primitive(seqs, masks, n_states=K, cyclic=False, floor=floor, n_iter=2, population=population)

    # The initialisation written out: equal time segments, moments over the measured frames, floored.
    seg = [np.minimum((np.arange(T) * K) // T, K - 1) for _ in seqs]
    x, m, s = np.concatenate(seqs), np.concatenate(masks), np.concatenate(seg)
    means0 = np.array([[x[(s == k) & m[:, f], f].mean() for f in range(F)] for k in range(K)])
    covars0 = np.maximum([[x[(s == k) & m[:, f], f].var() for f in range(F)] for k in range(K)], floor)
    start0, trans0 = np.eye(K)[0], left_to_right(K, T / K, False)
    want = _brute_force_baum_welch(seqs, [mk.astype(float) for mk in masks], start0, trans0, means0, covars0,
                                   floor, n_iter=2)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-7, atol=1e-9)
    assert np.any(np.isclose(got[1][:, 0], floor[0]))                   # the floor binds somewhere

    posthoc = _brute_force_baum_welch(seqs, [mk.astype(float) for mk in masks], start0, trans0, means0,
                                      covars0, floor, n_iter=2, floor_each_step=False)
    assert not np.allclose(posthoc[0], got[0], rtol=1e-4)
    unmasked = fit_primitive(seqs, [np.ones((T, F), dtype=bool)] * 3, n_states=K, cyclic=False, floor=floor,
                             n_iter=2, population=population)
    assert not np.allclose(unmasked[0], got[0], rtol=1e-4)
