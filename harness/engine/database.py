"""The motion database: one left-to-right Gaussian HMM per motion primitive, learned in joint space.

Each primitive ``c`` is an HMM with ``K`` states; state ``k`` emits the feature vector
``f = [theta, theta_dot, v, omega]`` (see ``features``) from ``N(mean[c, k], diag(covar[c, k]))``.
Transitions go from a state to itself or to the next one (left-to-right); cyclic primitives (walk, run, ...)
start with a transition from the last state back to the first, which Baum-Welch keeps only if demonstrations
wrap: cut into ``K`` segments each, they end in the last state, and the wrap is learned to zero. Training is
Baum-Welch (hmmlearn) from several demonstrations, initialised by cutting every demonstration into ``K`` equal
time segments, which keeps the states ordered in time and makes EM deterministic; every variance keeps a
per-feature floor (the human floor, ``variance_floor``), and a demonstration trains only the features it
measures (``training``).

**Both hands** (``mirrored``, the default). A demonstrator performs a one-sided primitive with one side, but a
test performer may use the other, and the tracker's twin pose sees every body mirrored. So each primitive's
HMM holds two chains of ``K`` states: chain A (states ``0..K-1``) is the HMM fitted on the demonstrations,
chain B (states ``K..2K-1``) its exact mirror image, ``mean_B = M mean_A`` and ``covar_B = |M| covar_A`` with
``M`` the features' mirror (``features.mirror_features``, a signed permutation), the same transitions within
each chain and none between them, and half the start probability on each::

    A = [[A_a, 0], [0, A_a]],    pi = [pi_a, pi_a] / 2

Then ``p(M y_1:T | c) = p(y_1:T | c)`` for every feature sequence: the database is closed under the mirror.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterable, Sequence
from pathlib import Path

import numba
import numpy as np

from harness.engine.features import (N_FEATURES, measured_features, mirror_features, mirror_variances,
                                     motion_features)
from harness.engine.training import (fit_background, fit_primitive, left_to_right,  # noqa: F401 (left_to_right re-exported)
                                     masked_moments)
from harness.engine.variance_floor import group_floor, variance_floor
from harness.engine.vector_math import EXP_MIN, FAST, exp_parts, log_normal
from harness.errors import EngineError
from harness.io import save_npz_atomic
from harness.motion.motion import Motion

DEFAULT_STATES = 20
_FORMAT = "harness-motion-database-1"
#: The background class's label: the database's "none of these" (``MotionDatabase(background=True)``).
UNKNOWN = "unknown"


def mirror_chains(means: np.ndarray, covars: np.ndarray, transmat: np.ndarray, startprob: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Both-handed HMMs from one-sided ones (module docstring): means and variances ``(C, K, 106)``, transitions
    ``(C, K, K)`` and start ``(C, K)`` become ``(C, 2K, 106)``, ``(C, 2K, 2K)`` block-diagonal and ``(C, 2K)``,
    chain A as given and chain B its mirror image."""
    C, K = startprob.shape
    trans = np.zeros((C, 2 * K, 2 * K))
    trans[:, :K, :K] = transmat
    trans[:, K:, K:] = transmat
    return (np.concatenate([means, mirror_features(means)], axis=1),
            np.concatenate([covars, mirror_variances(covars)], axis=1), trans,
            0.5 * np.concatenate([startprob, startprob], axis=1))


class MotionDatabase:
    """One HMM per primitive over joint-space features.

    Hyperparameters: ``n_states`` (K), ``cyclic`` (names of primitives whose last state starts with a wrap to the
    first, module docstring; the data source knows them, e.g. ``harness.motion.performer.CYCLIC``), ``n_iter``
    (Baum-Welch iterations), ``mirrored`` (each HMM also holds its mirror-image chain: ``S = 2K`` states, module
    docstring; else ``S = K``), ``floor`` (``(106,)`` variance floor per feature, kept by every M-step; default
    ``variance_floor()``), ``background`` (also a class ``unknown``: an ergodic HMM of every class's frames
    pooled, ``training.fit_background``, the database's "none of these"), ``by_source`` (a chain per source of
    demonstrations in each primitive: ``procedural``, each capture set; module docstring).
    Learned (after ``fit``): ``classes_`` (C,), ``cyclic_`` (C,) bool (whether each primitive's HMM started with
    a wrap), ``means_`` (C, S, 106), ``covars_`` (C, S, 106) diagonal variances, ``transmat_`` (C, S, S),
    ``startprob_`` (C, S), ``fps_``. Users of the HMMs take ``S`` from the arrays, not from ``n_states``.
    """

    def __init__(self, n_states: int = DEFAULT_STATES, *, cyclic: Iterable[str] = (), n_iter: int = 15,
                 mirrored: bool = True, floor: np.ndarray | None = None, background: bool = False,
                 by_source: bool = False):
        if n_states < 2:
            raise EngineError(f"n_states must be >= 2, got {n_states}")
        if n_iter < 0:
            raise EngineError(f"n_iter must be >= 0, got {n_iter}")
        self.n_states = int(n_states)
        self.cyclic = tuple(cyclic)
        self.n_iter = int(n_iter)
        self.mirrored = bool(mirrored)
        self.background = bool(background)
        self.by_source = bool(by_source)
        self.sources_: tuple[str, ...] = ()
        self.floor = variance_floor() if floor is None else np.asarray(floor, dtype=float)
        if self.floor.shape != (N_FEATURES,) or not np.all(np.isfinite(self.floor)) or np.any(self.floor <= 0):
            raise EngineError(f"floor must be {N_FEATURES} positive variances, got shape {self.floor.shape}")

    # --- learning -------------------------------------------------------------------------------

    def fit(self, motions: Sequence[Motion], population: Sequence[Motion] | None = None) -> "MotionDatabase":
        """Learn one HMM per label found in ``motions`` (several demonstrations each, one fps). A feature no
        demonstration of a class measures takes the Gaussian of the measured frames of ``population`` (default:
        ``motions``; ``training``)."""
        if not motions:
            raise EngineError("no training motions given")
        fps = {m.fps for m in motions}
        if len(fps) != 1:
            raise EngineError(f"training motions must share one frame rate, got {sorted(fps)}")
        classes = sorted({m.label for m in motions})
        if UNKNOWN in classes:
            raise EngineError(f"{UNKNOWN!r} is the background class's label, not a primitive's")
        classes += [UNKNOWN] if self.background else []
        K = self.n_states
        floor = self.floor
        self.sources_ = tuple(sorted({m.source for m in motions})) if self.by_source else ("",)
        G = len(self.sources_)
        means = np.empty((len(classes), G * K, N_FEATURES))
        covars = np.empty_like(means)
        trans = np.zeros((len(classes), G * K, G * K))
        start = np.zeros((len(classes), G * K))
        feats = [motion_features(m) for m in motions]
        masks = [np.broadcast_to(measured_features(m), f.shape) for m, f in zip(motions, feats)]
        population = self._population(motions if population is None else population)
        for c, label in enumerate(classes):
            if label == UNKNOWN:
                chain = fit_background(feats, masks, n_states=K, floor=floor, population=population)
                self._place(c, [chain] * G, [True] * G, (means, covars, trans, start))
                continue
            own = [i for i, m in enumerate(motions) if m.label == label]
            short = [len(feats[i]) for i in own if len(feats[i]) < K]
            if short:
                raise EngineError(f"class {label!r}: a demonstration of {short[0]} frames is shorter than "
                                  f"the {K} states")
            groups = [[i for i in own if not self.by_source or motions[i].source == s] for s in self.sources_]
            chains = {g: fit_primitive([feats[i] for i in idx], [masks[i] for i in idx], n_states=K,
                                       cyclic=label in self.cyclic, floor=floor, n_iter=self.n_iter,
                                       population=population) for g, idx in enumerate(groups) if idx}
            first = next(iter(chains.values()))
            # A source without demonstrations of the class keeps a copy of a chain, never entered (start 0).
            self._place(c, [chains.get(g, first) for g in range(G)], [g in chains for g in range(G)],
                        (means, covars, trans, start))
        self.classes_ = np.array(classes)
        self.cyclic_ = np.isin(self.classes_, list(self.cyclic))
        if self.mirrored:
            means, covars, trans, start = mirror_chains(means, covars, trans, start)
        self.means_, self.covars_, self.transmat_, self.startprob_ = means, covars, trans, start
        self.fps_ = float(fps.pop())
        return self

    def _place(self, c: int, chains: list, live: list[bool], out: tuple) -> None:
        """Class ``c``'s chains side by side in ``out`` (means, covars, transitions, start): block-diagonal
        transitions, the start shared equally by the live chains."""
        means, covars, trans, start = out
        K = self.n_states
        for g, (m, v, a, pi) in enumerate(chains):
            span = slice(g * K, (g + 1) * K)
            means[c, span], covars[c, span], trans[c, span, span] = m, v, a
            start[c, span] = pi / sum(live) if live[g] else 0.0

    def _population(self, motions: Sequence[Motion]) -> tuple[np.ndarray, np.ndarray]:
        """``(106,)`` mean and variance of the measured frames of ``motions`` (no frame: 0 and the floor)."""
        feats = [motion_features(m) for m in motions]
        mask = np.concatenate([np.broadcast_to(measured_features(m), f.shape) for m, f in zip(motions, feats)])
        mean, var, _ = masked_moments(np.concatenate(feats), mask.astype(float), np.ones((1, len(mask))),
                                      (np.zeros((1, N_FEATURES)), self.floor[None]))
        return mean[0], var[0]

    # --- use ------------------------------------------------------------------------------------

    def _check_fitted(self) -> None:
        if not hasattr(self, "means_"):
            raise EngineError("the motion database is not trained: call fit() or MotionDatabase.load()")

    @property
    def primitives(self) -> np.ndarray:
        """The classes that are primitives (all but the background class ``unknown``)."""
        self._check_fitted()
        return self.classes_[self.classes_ != UNKNOWN]

    @property
    def n_classes(self) -> int:
        self._check_fitted()
        return len(self.classes_)

    @property
    def n_chains(self) -> int:
        """Chains of ``n_states`` states per primitive: one per source (``by_source``), twice for a both-handed
        database."""
        return (2 if self.mirrored else 1) * max(1, len(self.sources_))

    def last_states(self) -> np.ndarray:
        """Indices of each chain's last state (a non-cyclic primitive's end rest, absorbing)."""
        return np.arange(1, self.n_chains + 1) * self.n_states - 1

    def feature_span(self) -> np.ndarray:
        """``(106,)`` the width of each feature's range under the database: from the lowest ``mean - 3 sd`` to the
        highest ``mean + 3 sd`` over every state (the support of ``log_emissions``' outlier term). The same for
        a feature and its mirror image, so a both-handed database stays closed under the mirror."""
        self._check_fitted()
        sd = np.sqrt(self.covars_)
        return (self.means_ + 3.0 * sd).max(axis=(0, 1)) - (self.means_ - 3.0 * sd).min(axis=(0, 1))

    def log_emissions(self, features: np.ndarray, outlier: float = 0.0,
                      measured: np.ndarray | None = None) -> np.ndarray:
        """Joint-space log densities ``(T, C, S)`` of features ``(T, 106)`` under every state.

        ``outlier`` (``eps``): each feature's density is ``(1 - eps) N(f; mean, var) + eps / span`` (``span``:
        ``feature_span``) instead of the Gaussian alone, the joint-space counterpart of the flows' outlier term:
        one feature a new performer holds far from every state (a posture, a style) costs at most
        ``log(eps / span)`` instead of growing with its squared distance, so it cannot hand the answer to the
        class whose Gaussians are broadest. ``measured`` ``(106,)`` bool: only these features are scored (the
        marginal over the others, the rule training follows, ``features.measured_features``)."""
        self._check_fitted()
        f = np.asarray(features, dtype=float)
        if f.ndim != 2 or f.shape[1] != N_FEATURES:
            raise EngineError(f"features must be (T, {N_FEATURES}), got {f.shape}")
        if not 0.0 <= outlier < 1.0:
            raise EngineError(f"outlier must be in [0, 1), got {outlier}")
        keep = np.ones(N_FEATURES, dtype=bool) if measured is None else np.asarray(measured, dtype=bool)
        if keep.shape != (N_FEATURES,):
            raise EngineError(f"measured must be ({N_FEATURES},) bool, got {keep.shape}")
        var = np.ascontiguousarray(self.covars_[..., keep])     # a mask on the last axis leaves it strided
        if outlier == 0.0:
            d = f[:, None, None, keep] - self.means_[None][..., keep]
            return (-0.5 * (d * d / var[None] + np.log(2 * np.pi * var[None]))).sum(axis=-1)
        out = np.empty((len(f),) + var.shape[:2])
        _robust_log_densities(np.ascontiguousarray(f[:, keep]), np.ascontiguousarray(self.means_[..., keep]),
                              1.0 / var, np.log1p(-outlier) - 0.5 * np.log(2 * np.pi * var),
                              np.log(outlier) - np.log(self.feature_span()[keep]), out)
        return out

    # --- files ----------------------------------------------------------------------------------

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The database as plain arrays (the ``.npz`` file's content)."""
        self._check_fitted()
        return {
            "format": np.array(_FORMAT), "classes": self.classes_.astype(str), "means": self.means_,
            "covars": self.covars_, "transmat": self.transmat_, "startprob": self.startprob_,
            "fps": np.array(self.fps_), "cyclic": np.array(self.cyclic, dtype=str),
            "n_iter": np.array(self.n_iter), "mirrored": np.array(self.mirrored), "floor": self.floor,
            "background": np.array(self.background), "sources": np.array(self.sources_, dtype=str),
        }

    def save(self, path: str | Path) -> None:
        save_npz_atomic(path, self.to_arrays())

    @classmethod
    def load(cls, path: str | Path) -> "MotionDatabase":
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["format"]) != _FORMAT:
                    raise EngineError(f"{path}: not a motion database (format mismatch, expected {_FORMAT!r})")
                # Files written before both-handed databases hold one chain.
                mirrored = bool(z["mirrored"]) if "mirrored" in z.files else False
                # Files written before issue 24 were trained with the group floor alone.
                floor = z["floor"].astype(float) if "floor" in z.files else group_floor()
                sources = tuple(str(s) for s in z["sources"]) if "sources" in z.files else ("",)
                db = cls(n_states=z["means"].shape[1] // ((2 if mirrored else 1) * len(sources)),
                         cyclic=[str(c) for c in z["cyclic"]], n_iter=int(z["n_iter"]), mirrored=mirrored,
                         floor=floor, background=bool(z["background"]) if "background" in z.files else False,
                         by_source=sources != ("",))
                db.sources_ = sources
                db.classes_ = z["classes"].astype(str)
                db.cyclic_ = np.isin(db.classes_, list(db.cyclic))
                db.means_, db.covars_ = z["means"].astype(float), z["covars"].astype(float)
                db.transmat_, db.startprob_ = z["transmat"].astype(float), z["startprob"].astype(float)
                db.fps_ = float(z["fps"])
        except FileNotFoundError:
            raise EngineError(f"{path}: no such database file") from None
        except KeyError as exc:
            raise EngineError(f"{path}: not a motion database (no array {exc.args[0]!r})") from None
        except (ValueError, TypeError, IndexError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # Empty, truncated or foreign files: the kind of failure, never the file's bytes.
            raise EngineError(f"{path}: not a motion database (empty, truncated or malformed: "
                              f"{type(exc).__name__})") from None
        try:
            return db.validate()
        except EngineError as exc:
            raise EngineError(f"{path}: {exc}") from None

    def validate(self) -> "MotionDatabase":
        """Check that the learned arrays agree in shape and are finite; raises EngineError naming the array."""
        self._check_fitted()
        C, K = len(self.classes_), self.means_.shape[1]
        if K != self.n_chains * self.n_states:
            raise EngineError(f"database means have {K} states, expected {self.n_chains} chains of {self.n_states}")
        expect = {"means": (C, K, N_FEATURES), "covars": (C, K, N_FEATURES), "transmat": (C, K, K),
                  "startprob": (C, K)}
        for name, shape in expect.items():
            a = getattr(self, name + "_")
            if a.shape != shape:
                raise EngineError(f"database {name} has shape {a.shape}, expected {shape} "
                                  f"({C} classes, {K} states, {N_FEATURES} features)")
            if not np.isfinite(a).all():
                raise EngineError(f"database {name} has NaN or infinite values")
        if np.any(self.covars_ <= 0):
            raise EngineError("database covars must be positive")
        return self


@numba.njit(cache=True, fastmath=FAST, error_model="numpy")
def _robust_log_densities(features, mean, inv_var, log_in, log_out, out):
    """``out[t, c, s] = sum_k logaddexp(log_in[c, s, k] - (f[t, k] - mean[c, s, k])^2 inv_var[c, s, k] / 2,
    log_out[k])``: ``log_emissions`` with an outlier share (``log_in`` holds the Gaussian's normaliser and the
    inlier share). As ``hi + log(1 + exp(lo - hi))`` with the exponential and the logarithm that vectorise over
    the features (``vector_math``): numpy's ``logaddexp`` made this 90% of the joint-space method's time."""
    T, K = features.shape
    C, S = mean.shape[:2]
    for t in range(T):
        f = features[t]
        for c in range(C):
            for s in range(S):
                m, iv, a = mean[c, s], inv_var[c, s], log_in[c, s]
                acc = 0.0
                for k in range(K):
                    d = f[k] - m[k]
                    z = a[k] - 0.5 * d * d * iv[k]
                    hi, lo = np.maximum(z, log_out[k]), np.minimum(z, log_out[k])     # NaN stays NaN, as in numpy
                    mantissa, scale = exp_parts(max(lo - hi, EXP_MIN))
                    acc += hi + log_normal(1.0 + mantissa * scale)
                out[t, c, s] = acc
