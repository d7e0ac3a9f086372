"""Recognition over a stream: the primitives' HMMs joined by a primitive-level transition matrix.

A person performs primitives one after another. The joint state is (primitive ``c``, state ``k``); from state
``j`` of primitive ``c`` the performer either goes on within ``c`` or leaves it, with probability ``e_c(j)``
(exit), for primitive ``c'`` chosen with probability ``P[c, c']``, entered at its entry distribution
``pi_c'``::

    p(c', k | c, j) = (1 - e_c(j)) A_c[j, k] [c' = c]  +  e_c(j) P[c, c'] pi_c'(k)

Every row sums to one, so the forward recursion ``alpha_t ∝ b_t * (alpha_{t-1} T)`` normalised over all
(primitive, state) pairs is the joint posterior ``p(c, k | y_0..t)`` and its normaliser is
``log p(y_t | y_<t)``, as in the isolated ``Recognizer`` (whose update, pruning and posteriors this class keeps;
only the prediction differs). The choices, with ``s`` the engine setting ``primitive_switch``:

- **exit states**: a non-cyclic primitive is left from its last state (its end rest; the left-to-right HMM of
  ``MotionDatabase`` makes that state absorbing), ``e_c(K-1) = s`` (each chain's last state in a both-handed
  database); a cyclic one (``db.cyclic_``: walk, run, ...) from any state, ``e_c(j) = s``, since a performer
  stops a gait anywhere in its cycle (leaving after a full cycle, from the last state, is one of these). ``s``
  is the per-frame probability of a primitive change from an exit state; for procedural streams it is one over
  their mean primitive duration in frames
  (``docs/streams.md``; the recognition measured on development streams hardly depends on it).
- **next primitive**: any primitive, uniformly, the same one included (a performer repeats squats):
  ``P[c, c'] = 1 / C``.
- **entry**: the database's start distribution with the same spread as the recursion's first frame,
  ``pi_c = (1 - start_spread) startprob_c + start_spread / K``: a primitive in a stream begins as its
  demonstrations began.

With ``s = 0`` the recursion is the isolated one (tested). ``online_labels`` turns the class posteriors into
the reported labels.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from harness.engine.database import MotionDatabase
from harness.engine.recognition import Recognizer, recognize_features
from harness.errors import EngineError


# Online segmentation: a new primitive is reported once it has been the most probable for this many frames in
# a row (see online_labels; chosen on development streams, docs/streams.md).
STREAM_MIN_FRAMES = 4


def exit_states(db: MotionDatabase) -> np.ndarray:
    """``(C, K)`` bool: the states a primitive may be left from (see the module docstring)."""
    C, K = db.startprob_.shape
    out = np.zeros((C, K), dtype=bool)
    out[:, db.last_states()] = True                 # the end rest of each chain (both sides, see database)
    out[db.cyclic_] = True
    return out


class SwitchingRecognizer(Recognizer):
    """Forward recursion over every primitive of a database, joined by primitive changes (module docstring).

    switch: ``s``, the per-frame exit probability from an exit state, in [0, 1). start_spread, prune: as for
    ``Recognizer`` (the start spread is also the entry spread).
    """

    def __init__(self, db: MotionDatabase, switch: float, start_spread: float = 0.05, prune: float = 1e-6):
        if not 0.0 <= switch < 1.0:
            raise EngineError(f"primitive switch probability must be in [0, 1), got {switch}")
        super().__init__(db, start_spread, prune)
        C, K = db.startprob_.shape
        exits = np.where(exit_states(db), switch, 0.0)
        entry = (1.0 - start_spread) * db.startprob_ + start_spread / K
        with np.errstate(divide="ignore"):
            self._log_within = np.log(db.transmat_)                       # (C, K, K)
            self._log_stay = np.log1p(-exits)                            # (C, K)
            self._log_exit = np.log(exits)                               # (C, K)
            self._log_next = np.full((C, C), -np.log(C))                 # (C, C): P[c, c']
            self._log_entry = np.log(entry)                              # (C, K)
        self.switch = float(switch)

    def reset(self) -> None:
        super().reset()
        self._updated = False

    def update(self, log_b: np.ndarray | None) -> float:
        norm = super().update(log_b)
        self._updated = True
        return norm

    def predict(self) -> None:
        """Move the posterior of the last frame through the joined transitions (the prior of the next frame)."""
        if not self._updated:
            return
        la = self.log_alpha
        stay = logsumexp(la[:, :, None] + self._log_stay[:, :, None] + self._log_within, axis=1)      # (C, K)
        leaving = logsumexp(la + self._log_exit, axis=1)                                           # (C,)
        arriving = logsumexp(leaving[:, None] + self._log_next, axis=0)                            # (C,)
        self.log_alpha = np.logaddexp(stay, arriving[:, None] + self._log_entry)

    def transition_matrix(self) -> np.ndarray:
        """The joint transition matrix ``(C K, C K)``, row ``c * K + j`` (for inspection and tests)."""
        C, K = self.log_alpha.shape
        within = np.exp(self._log_stay)[:, :, None] * np.exp(self._log_within)
        out = np.exp(self._log_exit).reshape(C * K, 1, 1) * np.exp(self._log_next).repeat(K, axis=0)[:, :, None] \
            * np.exp(self._log_entry)[None]
        out = out.reshape(C * K, C * K)
        for c in range(C):
            out[c * K:(c + 1) * K, c * K:(c + 1) * K] += within[c]
        return out


def recognize_stream_features(db: MotionDatabase, features: np.ndarray, switch: float,
                              start_spread: float = 0.05, measured: np.ndarray | None = None) -> np.ndarray:
    """Joint-space recognition over a stream (the upper-bound baseline): class posteriors ``(T, C)``
    (``recognize_features``' emissions)."""
    return recognize_features(db, features, recognizer=SwitchingRecognizer(db, switch, start_spread=start_spread,
                                                                           prune=0.0), measured=measured)


def online_labels(class_posterior: np.ndarray, min_frames: int) -> np.ndarray:
    """Per-frame primitive indices ``(T,)`` from class posteriors ``(T, C)``, decided online: the label starts as
    the first frame's most probable primitive and changes to another at the frame where that one has been the
    most probable for ``min_frames`` frames in a row (so a change is reported ``min_frames - 1`` frames after it
    began, and a lead shorter than ``min_frames`` frames is not reported). ``min_frames = 1`` is the per-frame
    argmax."""
    post = np.asarray(class_posterior, dtype=float)
    if post.ndim != 2 or len(post) == 0:
        raise EngineError(f"class posteriors must be (T, C) with T >= 1, got {post.shape}")
    if min_frames < 1:
        raise EngineError(f"min_frames must be at least 1, got {min_frames}")
    best = np.argmax(post, axis=1)
    out = np.empty(len(best), dtype=int)
    current, run = best[0], 0
    for t, b in enumerate(best):
        run = run + 1 if t > 0 and b == best[t - 1] else 1
        if b != current and run >= min_frames:
            current = b
        out[t] = current
    return out

