"""``benchmarks/database_rules.py``'s scoring of a capture with a posture offset per class (a measured and
rejected alternative in docs/log/2026-12-07-posture-offset.md): its forward-backward against hmmlearn's, and its offset
integrated out against the closed form of the linear-Gaussian model it is exact for."""

import sys
from pathlib import Path

import numpy as np
from hmmlearn.hmm import GaussianHMM
from scipy.stats import multivariate_normal

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from harness.engine import MotionDatabase  # noqa: E402
from harness.engine.features import ANGLES, N_FEATURES  # noqa: E402
from database_rules import adapted_log_likelihoods, forward_backward  # noqa: E402


def _database(means, covars, transmat, startprob) -> MotionDatabase:
    db = MotionDatabase(2, mirrored=False)
    db.classes_ = np.array([f"c{i}" for i in range(len(means))])
    db.cyclic_ = np.zeros(len(means), dtype=bool)
    db.means_, db.covars_, db.transmat_, db.startprob_ = means, covars, transmat, startprob
    db.fps_ = 30.0
    return db.validate()


def test_forward_backward_is_hmmlearns():
    rng = np.random.default_rng(0)
    hmm = GaussianHMM(3, covariance_type="diag", init_params="", params="")
    hmm.startprob_ = np.array([0.6, 0.3, 0.1])
    hmm.transmat_ = np.array([[0.8, 0.2, 0.0], [0.0, 0.7, 0.3], [0.1, 0.0, 0.9]])
    means, covars = rng.normal(0, 1, (3, 2)), rng.uniform(0.2, 1.0, (3, 2))
    hmm.n_features, hmm.means_, hmm.covars_ = 2, means, covars
    x = rng.normal(0, 1, (25, 2))
    log_b = np.stack([multivariate_normal.logpdf(x, means[s], np.diag(covars[s])) for s in range(3)], axis=1)
    with np.errstate(divide="ignore"):
        ll, gamma = forward_backward(log_b, np.log(hmm.startprob_), np.log(hmm.transmat_))
    np.testing.assert_allclose(ll, hmm.score(x), rtol=1e-10)
    np.testing.assert_allclose(gamma, hmm.predict_proba(x), atol=1e-10)


def test_the_offset_is_integrated_out_exactly_for_a_gaussian_model():
    """Both states of each class alike: the capture's measured angle ``j`` is ``mean_j + delta_j + noise``, so its
    frames are jointly ``N(mean_j 1, var_j I + sigma^2 1 1^T)`` and every other measured feature independent;
    Laplace's method is exact there (and one EM step finds the offset)."""
    rng = np.random.default_rng(1)
    T, sigma = 12, 0.2
    means = np.repeat(rng.normal(0, 0.5, (2, 1, N_FEATURES)), 2, axis=1)
    covars = np.repeat(rng.uniform(0.01, 0.05, (2, 1, N_FEATURES)), 2, axis=1)
    db = _database(means, covars, np.full((2, 2, 2), 0.5), np.full((2, 2), 0.5))
    measured = np.ones(N_FEATURES, dtype=bool)
    measured[[3, 7, 60]] = False
    f = means[0, 0] + rng.normal(0, 0.2, N_FEATURES) + rng.normal(0, 0.1, (T, N_FEATURES))
    got = adapted_log_likelihoods(db, f, measured, outlier=0.0, sigma=sigma)
    angles = np.zeros(N_FEATURES, dtype=bool)
    angles[ANGLES] = True
    for c in range(2):
        mu, var = means[c, 0], covars[c, 0]
        want = sum(multivariate_normal.logpdf(f[:, j], np.full(T, mu[j]), var[j] * np.eye(T) + sigma**2)
                   for j in np.flatnonzero(measured & angles))
        want += sum(multivariate_normal.logpdf(f[:, j], np.full(T, mu[j]), var[j] * np.eye(T))
                    for j in np.flatnonzero(measured & ~angles))
        np.testing.assert_allclose(got[c], want, rtol=1e-9)
    plain = adapted_log_likelihoods(db, f, measured, outlier=0.0, sigma=0.0)
    assert plain[0] < got[0]            # an offset the capture has is paid for less than its squared distance
