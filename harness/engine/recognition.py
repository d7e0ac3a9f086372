"""Online recognition: a forward recursion per primitive, normalised jointly over (primitive, state).

``alpha_t(c, k) ∝ b_t(c, k) sum_j alpha_{t-1}(c, j) A_c[j, k]`` with ``alpha_0(c, k) ∝ pi_c(k) b_0(c, k)``
and a uniform prior over primitives. Normalising over all (c, k) makes ``alpha_t`` the joint posterior
``p(c, k | y_0..t)``; its sum over ``k`` is the class posterior. The emission ``b_t`` may come from joint-space
features (the upper-bound baseline) or from image flows (the engine); the recursion is the same.
"""

from __future__ import annotations

import numba
import numpy as np

from harness.engine.database import MotionDatabase
from harness.errors import EngineError


class Recognizer:
    """Forward recursion over every primitive of a database, with pruning of negligible states.

    start_spread: probability mass of the start distribution spread uniformly over all states (so that a
    demonstration that starts mid-primitive can still be followed). prune: states whose posterior is below
    ``prune`` times the largest of their primitive are not evaluated (their emission is set to the worst evaluated one).
    """

    def __init__(self, db: MotionDatabase, start_spread: float = 0.05, prune: float = 1e-6):
        db.validate()
        if not 0.0 <= start_spread <= 1.0:
            raise EngineError(f"start_spread must be in [0, 1], got {start_spread}")
        if not 0.0 <= prune < 1.0:
            raise EngineError(f"prune must be in [0, 1), got {prune}")
        self.db = db
        C, K = db.startprob_.shape
        start = (1.0 - start_spread) * db.startprob_ + start_spread / K
        with np.errstate(divide="ignore"):
            self._log_start = np.log(start) - np.log(C)
        self._trans = np.asarray(db.transmat_, dtype=float)
        self._start_states = _state_rows(self._log_start)    # a primitive outside the belief keeps these
        self._log_prune = np.log(prune) if prune > 0 else -np.inf
        self.reset()

    def reset(self) -> None:
        self.log_alpha = self._log_start.copy()   # the prior of frame 0
        self._started = False

    def __copy__(self) -> "Recognizer":
        # A snapshot shares every array (they are replaced, never changed in place: ``log_alpha``). The instance's
        # attributes copied directly: copy's generic reduce protocol took 5 us, once per track and frame.
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        return new

    @property
    def log_alpha(self) -> np.ndarray:
        """``(C, K)`` log joint posterior (normalised after ``update``). Arrays are replaced, never changed in
        place, so a shallow copy of the recognizer is a snapshot; the quantities derived from it are cached until
        it changes."""
        return self._log_alpha

    @log_alpha.setter
    def log_alpha(self, value: np.ndarray) -> None:
        self._log_alpha = value
        self._derived: tuple = ()

    def restrict(self, primitives: np.ndarray) -> "Recognizer":
        """Start anew believing only ``primitives`` (indices or a ``(C,)`` mask), each with its start
        distribution and equal shares: the recursion of a track that hypothesises those primitives (the others
        have zero probability and are never evaluated). Returns itself."""
        keep = np.zeros(self._log_start.shape[0], dtype=bool)
        keep[primitives] = True
        if not keep.any():
            raise EngineError("a belief must keep at least one primitive")
        start = self._log_start - np.log(keep.mean())
        self._log_start = np.where(keep[:, None], start, -np.inf)
        self.reset()
        return self

    def predict(self) -> None:
        """Move the posterior of the last frame through the transitions (the prior of the next frame)."""
        if not self._started:
            return
        self._set_derived(*_predicted_derived(self.log_alpha, self._trans, self._start_states, self._log_prune))

    def active(self) -> np.ndarray:
        """``(C, K)`` bool: the states worth evaluating in the coming update.

        Pruning is relative to the best state *of the same primitive*: a primitive that is unlikely now must
        still follow its own states, or it could never come back when its distinctive phase (the flight of a
        jump) arrives."""
        return self._all()[3]

    def update(self, log_b: np.ndarray | None) -> float:
        """Fold in one frame's emission log-likelihoods ``(C, K)``; entries of inactive states are ignored.
        Returns the recursion's normaliser ``log p(y_t | y_<t) = log sum_ck alpha_t|t-1(c, k) b_t(c, k)``
        (the classes and states summed out): summed over frames it is the evidence of the pose path the
        emissions were evaluated along.

        ``None`` (or an all-zero array) means a frame without evidence: the belief only moves.
        """
        if log_b is not None:
            log_b = np.asarray(log_b, dtype=float)
            if log_b.shape != self.log_alpha.shape:
                raise EngineError(f"emissions must be {self.log_alpha.shape}, got {log_b.shape}")
        *derived, norm = _updated_derived(self.log_alpha, self.active(), log_b, self._start_states, self._log_prune)
        self._set_derived(*derived)
        self._started = True
        return norm

    def _set_derived(self, log_alpha: np.ndarray, *derived) -> None:
        """A new ``log_alpha`` with its derived quantities (``_derived``), computed in the same kernel call as it:
        every step's are read before the next step (a call of its own cost 3-4 us a track and frame)."""
        self.log_alpha = log_alpha
        self._derived = derived

    def _all(self) -> tuple:
        """The posteriors and active states of the current ``log_alpha``, computed together once
        (``_derived``)."""
        if not self._derived:
            self._derived = _derived(self.log_alpha, self._start_states, self._log_prune)
        return self._derived

    @property
    def posterior(self) -> np.ndarray:
        """``(C, K)`` joint posterior over primitives and states (``log_alpha`` is kept normalised; read-only)."""
        return self._all()[0]

    @property
    def state_posterior(self) -> np.ndarray:
        """``(C, K)`` posterior over states given each primitive (rows sum to one, even for a primitive whose
        own probability underflows; a primitive outside the belief keeps its start distribution's shape, and is
        never read; read-only)."""
        return self._all()[1]

    @property
    def class_posterior(self) -> np.ndarray:
        """``(C,)`` posterior over primitives (read-only)."""
        return self._all()[2]


# The recursion's steps compiled: a track's belief is a few hundred numbers, and the same steps in numpy cost
# 20-30 us a call in call overhead, once per track and frame (docs/log/2026-12-05-speed-step-07.md).

@numba.njit(cache=True)
def _predicted(log_alpha, trans):
    """``log sum_j alpha(c, j) A_c[j, k]``, in probability space about each primitive's best state; a
    primitive outside the belief (-inf throughout) stays so."""
    C, K = log_alpha.shape
    out = np.full((C, K), -np.inf)
    p = np.empty(K)
    for c in range(C):
        top = log_alpha[c].max()
        if not np.isfinite(top):
            continue
        for j in range(K):
            p[j] = np.exp(log_alpha[c, j] - top)
        for k in range(K):
            acc = 0.0
            for j in range(K):
                acc += p[j] * trans[c, j, k]
            out[c, k] = np.log(acc) + top if acc > 0.0 else -np.inf
    return out


@numba.njit(cache=True)
def _updated(log_alpha, active, log_b):
    """``log_alpha + log_b`` on the active states (the others take the worst active emission; no emission:
    ``None``), normalised; returns it and the normaliser ``log sum exp``."""
    C, K = log_alpha.shape
    out = log_alpha.copy()
    # A primitive outside the belief (-inf throughout) stays so and adds nothing: its row is skipped (a track of
    # one primitive leaves nine of ten rows so).
    inside = np.empty(C, dtype=np.bool_)
    for c in range(C):
        inside[c] = np.isfinite(log_alpha[c].max())
    if log_b is not None:
        worst = np.inf
        for c in range(C):
            for k in range(K):
                if active[c, k]:
                    worst = min(worst, log_b[c, k])
        for c in range(C):
            if inside[c]:
                for k in range(K):
                    out[c, k] += log_b[c, k] if active[c, k] else worst
    top = out.max()
    shift = top if np.isfinite(top) else 0.0
    acc = 0.0
    for c in range(C):
        if inside[c]:
            for k in range(K):
                acc += np.exp(out[c, k] - shift)
    norm = np.log(acc) + shift if acc > 0.0 else -np.inf
    for c in range(C):
        if inside[c]:
            for k in range(K):
                out[c, k] -= norm
    return out, norm


@numba.njit(cache=True)
def _predicted_derived(log_alpha, trans, start_states, log_prune):
    """``_predicted`` and the ``_derived`` quantities of its result, in one call."""
    out = _predicted(log_alpha, trans)
    post, state, cls, active = _derived(out, start_states, log_prune)
    return out, post, state, cls, active


@numba.njit(cache=True)
def _updated_derived(log_alpha, active, log_b, start_states, log_prune):
    """``_updated`` and the ``_derived`` quantities of its result, in one call (the normaliser last)."""
    out, norm = _updated(log_alpha, active, log_b)
    post, state, cls, new_active = _derived(out, start_states, log_prune)
    return out, post, state, cls, new_active, norm


@numba.njit(cache=True)
def _state_row(row, out):
    """``out = exp(row - max) / sum``: a primitive's state posterior from its row of a log joint posterior."""
    best = row.max()
    z = 0.0
    for k in range(len(row)):
        out[k] = np.exp(row[k] - best)
        z += out[k]
    for k in range(len(row)):
        out[k] /= z


@numba.njit(cache=True)
def _state_rows(log_alpha):
    """``(C, K)``: every primitive's state posterior (``_state_row``)."""
    out = np.empty(log_alpha.shape)
    for c in range(log_alpha.shape[0]):
        _state_row(log_alpha[c], out[c])
    return out


@numba.njit(cache=True)
def _derived(log_alpha, start_states, log_prune):
    """The joint posterior ``(C, K)``, the state posterior per primitive ``(C, K)`` (``start_states``' row for a
    primitive outside the belief, -inf throughout), the class posterior ``(C,)`` and the states worth evaluating
    ``(C, K)`` (at least ``log_prune`` of their primitive's best, and possible) of a log joint posterior."""
    C, K = log_alpha.shape
    post = np.zeros((C, K))
    state = np.empty((C, K))
    cls = np.zeros(C)
    active = np.zeros((C, K), dtype=np.bool_)
    top = log_alpha.max()
    own = np.empty(C)                       # each primitive's best state (-inf: outside the belief)
    total = 0.0
    for c in range(C):
        own[c] = log_alpha[c].max()
        if np.isfinite(own[c]):
            for k in range(K):
                post[c, k] = np.exp(log_alpha[c, k] - top)
                total += post[c, k]
    for c in range(C):
        if not np.isfinite(own[c]):         # outside the belief: no mass, nothing to evaluate
            state[c] = start_states[c]
            continue
        _state_row(log_alpha[c], state[c])
        mass = 0.0
        for k in range(K):
            post[c, k] /= total
            mass += post[c, k]
            active[c, k] = (log_alpha[c, k] >= own[c] + log_prune) and np.isfinite(log_alpha[c, k])
        cls[c] = mass
    cls /= cls.sum()
    return post, state, cls, active


# The joint-space recognition's per-feature outlier share (``MotionDatabase.log_emissions``). Chosen on the
# capture scenarios' development captures (``benchmarks/database_rules.py --outliers``): 163 of 195 right,
# 0.03 and 0.1 one fewer, the plain Gaussian 152 (docs/log/2026-12-03-feature-outlier-share.md).
FEATURE_OUTLIER = 0.05


def recognize_features(db: MotionDatabase, features: np.ndarray, start_spread: float = 0.05,
                       recognizer: Recognizer | None = None, outlier: float = FEATURE_OUTLIER,
                       measured: np.ndarray | None = None) -> np.ndarray:
    """Joint-space recognition (the upper-bound baseline): class posteriors ``(T, C)`` from true features, by
    ``recognizer`` (default: a fresh ``Recognizer`` without pruning), with ``outlier`` and ``measured`` as in
    ``MotionDatabase.log_emissions`` (``outlier=0``: the HMMs' plain Gaussian emissions)."""
    rec = recognizer if recognizer is not None else Recognizer(db, start_spread=start_spread, prune=0.0)
    log_b = db.log_emissions(features, outlier=outlier, measured=measured)
    out = np.empty((len(log_b), db.n_classes))
    for t in range(len(log_b)):
        rec.predict()
        rec.update(log_b[t])
        out[t] = rec.class_posterior
    return out
