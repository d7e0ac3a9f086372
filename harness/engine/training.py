"""Baum-Welch for one primitive's HMM under the database's training rules (hmmlearn's diagonal Gaussian HMM).

- **Initialisation**: every demonstration cut into ``K`` equal time segments (means and variances per segment),
  left-to-right transitions (``left_to_right``): the states stay ordered in time and EM is deterministic.
- **Variance floor**: every M-step keeps each variance at or above its feature's floor
  (``variance_floor``). Per state and feature the variance's log-likelihood is unimodal with its maximum at the
  unconstrained estimate, so under ``var >= floor`` the M-step's maximiser is ``max(estimate, floor)``; the
  means are then fitted under the variances the database will use, not under collapsed ones.
- **Measured features**: a demonstration trains only the features it measures (``features.measured_features``).
  A capture whose format holds the wrist at the retargeting's warm start would otherwise teach its class that
  wrists never move, and every real wrist would then fall outside the class. With the mask ``m_tf`` (1: frame
  ``t`` measures feature ``f``) the E-step's emission is the marginal of the diagonal Gaussian over the
  measured features, and the M-step's sums run over the frames that measure each feature::

      mu_kf = sum_t gamma_t(k) m_tf y_tf / sum_t gamma_t(k) m_tf
      var_kf = max(sum_t gamma_t(k) m_tf (y_tf - mu_kf)^2 / sum_t gamma_t(k) m_tf, floor_f)

  A feature that no demonstration of the class measures keeps the ``population`` Gaussian it starts from
  (the training set's measured frames of every class): the class claims nothing about it beyond what the
  demonstrators do in general.

A state (or a state's feature) that no frame reaches any more keeps its previous parameters (hmmlearn would
divide zero by zero).
"""

from __future__ import annotations

import logging

import numpy as np
from hmmlearn import _utils
from hmmlearn.hmm import GaussianHMM

from harness.errors import EngineError

# Expected frames below which Baum-Welch keeps a state's (or a state feature's) previous parameters: no data left
# to estimate them from.
_EMPTY_OCCUPANCY = 1e-10


def left_to_right(n_states: int, mean_dwell: float, cyclic: bool) -> np.ndarray:
    """``(K, K)`` transition matrix: stay with probability ``1 - 1/dwell``, else step to the next state."""
    if n_states < 1:
        raise EngineError(f"n_states must be >= 1, got {n_states}")
    step = 1.0 / max(mean_dwell, 1.0)
    a = np.eye(n_states) * (1.0 - step)
    a[np.arange(n_states - 1), np.arange(1, n_states)] = step
    if cyclic:
        a[-1, 0] = step
    else:
        a[-1, -1] = 1.0
    return a


def masked_moments(x: np.ndarray, mask: np.ndarray, weights: np.ndarray, fallback: tuple[np.ndarray, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted mean and variance per feature of ``x`` ``(T, F)`` over the frames whose ``mask`` ``(T, F)`` is
    set, for each row of ``weights`` ``(K, T)``: ``(K, F)`` means, ``(K, F)`` variances and ``(K, F)`` weight
    sums. Where a row's weight sum is empty, the ``fallback`` ``((K, F), (K, F))`` means and variances."""
    w = weights @ mask                                                  # (K, F)
    seen = w > _EMPTY_OCCUPANCY
    safe = np.where(seen, w, 1.0)
    mean = np.where(seen, weights @ (mask * x) / safe, fallback[0])
    second = weights @ (mask * x * x) / safe
    var = np.where(seen, np.maximum(second - mean**2, 0.0), fallback[1])
    return mean, var, w


class _PrimitiveHMM(GaussianHMM):
    """hmmlearn's diagonal Gaussian HMM with the module's floor and measured-feature masks (set before
    ``fit``: ``variance_floor`` ``(F,)`` and ``masks``, one ``(T_i, F)`` bool array per sequence)."""

    variance_floor: np.ndarray
    masks: list[np.ndarray]
    _mask: np.ndarray | None = None         # the mask of the sequence in the E-step (None: all measured)

    def _do_estep(self, X, lengths):
        # hmmlearn's E-step, with the sequence's mask made known to the emission and the statistics.
        impl = {"scaling": self._fit_scaling, "log": self._fit_log}[self.implementation]
        stats = self._initialize_sufficient_statistics()
        self._estep_begin()
        log_prob = 0.0
        try:
            for sub_x, mask in zip(_utils.split_X_lengths(X, lengths), self.masks, strict=True):
                self._mask = mask
                lattice, lp, posteriors, fwd, bwd = impl(sub_x)
                self._accumulate_sufficient_statistics(stats, sub_x, lattice, posteriors, fwd, bwd)
                log_prob += lp
        finally:
            self._mask = None
        return stats, log_prob

    def _compute_log_likelihood(self, X):
        if self._mask is None:
            return super()._compute_log_likelihood(X)
        var = self._covars_[None]
        d = X[:, None, :] - self.means_[None]
        return -0.5 * np.sum(self._mask[:, None, :] * (d * d / var + np.log(2.0 * np.pi * var)), axis=-1)

    def _initialize_sufficient_statistics(self):
        stats = super()._initialize_sufficient_statistics()
        stats["mask_post"] = np.zeros((self.n_components, self.n_features))
        stats["mask_obs"] = np.zeros((self.n_components, self.n_features))
        stats["mask_obs**2"] = np.zeros((self.n_components, self.n_features))
        return stats

    def _accumulate_sufficient_statistics(self, stats, X, lattice, posteriors, fwdlattice, bwdlattice):
        super()._accumulate_sufficient_statistics(stats, X, lattice, posteriors, fwdlattice, bwdlattice)
        mask = np.ones_like(X) if self._mask is None else self._mask.astype(float)
        stats["mask_post"] += posteriors.T @ mask
        stats["mask_obs"] += posteriors.T @ (mask * X)
        stats["mask_obs**2"] += posteriors.T @ (mask * X * X)

    def _do_mstep(self, stats):
        means, covars, trans = self.means_.copy(), self._covars_.copy(), self.transmat_.copy()
        # start and transition probabilities; its means and variances are redone below (a state no frame reaches
        # divides zero by zero there, which the masked estimate replaces)
        with np.errstate(invalid="ignore", divide="ignore"):
            super()._do_mstep(stats)
        w = stats["mask_post"]
        seen = w > _EMPTY_OCCUPANCY
        safe = np.where(seen, w, 1.0)
        new_means = stats["mask_obs"] / safe
        # hmmlearn's estimate (its covariance prior included), over the frames that measure each feature.
        spread = np.maximum(stats["mask_obs**2"] - new_means**2 * w, 0.0)
        new_var = (self.covars_prior + spread) / np.maximum(w, 1e-5)
        self.means_ = np.where(seen, new_means, means)
        self._covars_ = np.where(seen, np.maximum(new_var, self.variance_floor), covars)
        lost = ~np.isclose(self.transmat_.sum(axis=1), 1.0)
        self.transmat_[lost] = trans[lost]


def fit_primitive(features: list[np.ndarray], masks: list[np.ndarray], *, n_states: int, cyclic: bool,
                  floor: np.ndarray, n_iter: int, population: tuple[np.ndarray, np.ndarray]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One primitive's HMM from its demonstrations' features ``[(T_i, F)]`` and measured-feature masks
    ``[(T_i, F)]`` bool (module docstring): means ``(K, F)``, variances ``(K, F)``, transitions ``(K, K)`` and
    start probabilities ``(K,)``. ``population``: the ``(F,)`` mean and variance of features the class never
    measures."""
    K = n_states
    x, m = np.concatenate(features), np.concatenate(masks).astype(float)
    seg = np.concatenate([np.minimum((np.arange(len(f)) * K) // len(f), K - 1) for f in features])
    # A state's feature no frame of its segment measures starts from the class's measured frames, and a feature
    # the class never measures from the population.
    whole = masked_moments(x, m, np.ones((1, len(x))), (population[0][None], population[1][None]))
    means, var, _ = masked_moments(x, m, (seg[None] == np.arange(K)[:, None]).astype(float),
                                   (np.repeat(whole[0], K, 0), np.repeat(whole[1], K, 0)))
    hmm = _PrimitiveHMM(n_components=K, covariance_type="diag", n_iter=n_iter, init_params="", params="stmc",
                        min_covar=1e-6, random_state=0, implementation="log")
    hmm.variance_floor, hmm.masks = floor, [mk.astype(bool) for mk in masks]
    hmm.startprob_ = np.eye(K)[0]
    hmm.transmat_ = left_to_right(K, np.mean([len(f) for f in features]) / K, cyclic)
    hmm.means_, hmm.covars_ = means, np.maximum(var, floor)
    if n_iter:
        # hmmlearn logs a warning when an EM step lowers the likelihood by rounding (the floored M-step is still
        # monotone: the previous variances were feasible); keep the log quiet.
        logger = logging.getLogger("hmmlearn.base")
        level = logger.level
        logger.setLevel(logging.ERROR)
        try:
            hmm.fit(x, [len(f) for f in features])
        finally:
            logger.setLevel(level)
    return hmm.means_, np.maximum(hmm._covars_, floor), hmm.transmat_, hmm.startprob_


def state_posteriors(means: np.ndarray, covars: np.ndarray, transmat: np.ndarray, startprob: np.ndarray,
                     features: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """``(T, S)`` smoothed state posteriors of one sequence ``(T, F)`` under an HMM (means and variances
    ``(S, F)``, transitions ``(S, S)``, start ``(S,)``), the emissions over its measured features ``mask``
    ``(F,)`` (None: all)."""
    hmm = _PrimitiveHMM(n_components=len(startprob), covariance_type="diag", implementation="log")
    hmm.n_features = features.shape[1]
    hmm.startprob_, hmm.transmat_, hmm.means_, hmm.covars_ = startprob, transmat, means, covars
    hmm._mask = None if mask is None else np.broadcast_to(mask, features.shape)
    return hmm.predict_proba(features)


def fit_background(features: list[np.ndarray], masks: list[np.ndarray], *, n_states: int, floor: np.ndarray,
                   population: tuple[np.ndarray, np.ndarray], dwell: float = 5.0,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A background ("none of these") HMM of every class's frames pooled: ``n_states`` states from k-means of
    the frames' angles (unmeasured angles at the population mean), each state's moments over its frames'
    measured features (variances floored), ergodic transitions (stay ``1 - 1/dwell``, the rest shared by the
    other states) and a uniform start. It explains any motion made of the database's postures in any order, so
    it loses to a primitive's chain on that primitive's motions and wins on motions no chain follows. Returns
    means ``(K, F)``, variances ``(K, F)``, transitions ``(K, K)`` and start ``(K,)``."""
    from scipy.cluster.vq import kmeans2

    from harness.engine.features import ANGLES

    K = n_states
    x, m = np.concatenate(features), np.concatenate(masks)
    angles = np.where(m[:, ANGLES], x[:, ANGLES], population[0][ANGLES])
    scale = np.sqrt(np.maximum(angles.var(axis=0), floor[ANGLES]))
    _, labels = kmeans2(angles / scale, K, minit="++", seed=np.random.default_rng(seed))
    weights = (labels[None] == np.arange(K)[:, None]).astype(float)
    means, var, _ = masked_moments(x, m.astype(float), weights, (np.repeat(population[0][None], K, 0),
                                                                 np.repeat(population[1][None], K, 0)))
    trans = np.full((K, K), (1.0 / dwell) / (K - 1))
    np.fill_diagonal(trans, 1.0 - 1.0 / dwell)
    return means, np.maximum(var, floor), trans, np.full(K, 1.0 / K)
