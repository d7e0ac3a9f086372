"""Time reversal: the database and the frames of a clip played backwards, for the offline backward pass.

The offline estimate may re-track a clip from its end (``backward.py``): the pose there has settled, while the
causal pass started from one frame's guess. Tracking backwards needs the database and the flows as they
would be if the clip ran backwards.

**Flows.** A flow is a backward difference, ``d_t = (p_t - p_{t-1}) fps`` at ``p_t``. Backwards in time the
point moves from ``p_t`` to ``p_{t-1}``: the same flow with its velocity negated, ``-d_t`` at ``p_t``, is that
motion (a forward difference in reversed time). Kept at ``p_t``, it pairs the position at ``t`` with the
velocity over ``(t - 1, t)``, as the database's states do (``features.VELOCITY_SCHEME``); the reversed clip's
own backward difference, ``-d_{t+1}`` at ``p_t``, would pair it with the velocity over ``(t, t + 1)``, a whole
frame of acceleration off. So the reversed clip's frame for time ``t`` is the forward frame ``t`` with its
velocities negated.

**Database.** Every velocity changes sign: the angle rates, the base's linear and angular velocity, and so
every model point's velocity ``J theta_dot + v + omega x x``. Its covariance ``H S_theta H^T + J S_rate J^T +
S_v + [x] S_omega [x]^T`` is unchanged (``H = Jdot + [omega] J`` changes sign with the rates and ``omega``),
so the point distributions reverse exactly by negating the velocity means. Positions are unchanged. A state
reached from ``j`` at rate ``A[j, k]`` is left towards ``j`` backwards: with the expected stay in a state
``d_k = 1 / (1 - A[k, k])`` (each state of a left-to-right chain is visited once),

    A_rev[k, k] = A[k, k],    A_rev[k, j] ∝ d_j A[j, k]  (j != k),  scaled to 1 - A[k, k]

(a state without a predecessor, the first of a non-cyclic chain, absorbs). The reversed chain starts where
the forward one ends: a non-cyclic chain's absorbing last state, anywhere in a cyclic one. That end state
absorbs forwards (an infinite stay) but must be left backwards: it takes the mean stay of its chain's other
states (left absorbing, the reversed recursion could never leave a clip's end rest, and pruning then lost the
other states: a bow scored 200 nats below its forward evidence along the true path).

The base moves backwards from ``t`` to ``t - 1`` by ``-v_t``, but the reversed loop predicts it with the
belief of frame ``t - 1``, ``-v_{t-1}``: the motion model is a frame off under acceleration (the process noise
covers it), the emissions are exact.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from harness.engine.database import MotionDatabase
from harness.engine.features import ANGLE_RATES, BASE_ANGULAR, BASE_LINEAR
from harness.engine.model import EngineModel

# Features whose sign time reversal flips: every velocity.
_VELOCITIES = np.zeros(2 * ANGLE_RATES.start + 6, dtype=bool)
for _sl in (ANGLE_RATES, BASE_LINEAR, BASE_ANGULAR):
    _VELOCITIES[_sl] = True
_REVERSAL_SIGN = np.where(_VELOCITIES, -1.0, 1.0)


def reversed_transitions(transmat: np.ndarray) -> np.ndarray:
    """``(..., S, S)``: each chain's transitions in reversed time (module docstring). A forward chain's absorbing
    last state (a non-cyclic primitive's end rest) is where the reversed chain starts; it must be left, so it
    takes the mean dwell of its chain's other states."""
    a = np.asarray(transmat, dtype=float)
    stay = np.diagonal(a, axis1=-2, axis2=-1).copy()
    absorbing = stay >= 1.0 - 1e-9
    chain = _chains(a)
    others = np.einsum("...ij,...j->...i", chain, np.where(absorbing, 0.0, stay))
    n_others = np.einsum("...ij,...j->...i", chain, (~absorbing).astype(float))
    stay = np.where(absorbing & (n_others > 0), others / np.maximum(n_others, 1), stay)
    dwell = 1.0 / np.maximum(1.0 - stay, 1e-12)
    eye = np.eye(a.shape[-1], dtype=bool)
    flow = np.where(eye, 0.0, np.swapaxes(a * dwell[..., :, None], -1, -2))     # flow[k, j] = d_j A[j, k]
    into = flow.sum(axis=-1, keepdims=True)
    out = np.where(into > 0, flow / np.where(into > 0, into, 1.0) * (1.0 - stay[..., :, None]), 0.0)
    # A state nothing leads into (the first of a non-cyclic chain) keeps its whole mass backwards.
    stay_rev = np.where(into[..., 0] > 0, stay, 1.0)
    return np.where(eye, stay_rev[..., :, None], out)


def _chains(a: np.ndarray) -> np.ndarray:
    """``(..., S, S)`` float: 1 where two states are in the same chain (connected by transitions either way)."""
    linked = (a > 0) | np.swapaxes(a > 0, -1, -2) | np.eye(a.shape[-1], dtype=bool)
    for _ in range(int(np.ceil(np.log2(a.shape[-1]))) + 1):
        linked = linked | ((linked.astype(float) @ linked.astype(float)) > 0)
    return linked.astype(float)


def reversed_start(transmat: np.ndarray, startprob: np.ndarray | None = None) -> np.ndarray:
    """``(..., S)``: where the reversed chains start: the forward chains' absorbing states, or, for a chain
    without one (cyclic), uniformly over it. The chains the forward recursion can enter (``startprob``; None:
    all) share the mass equally, as their forward starts do; a chain it never enters (a source without
    demonstrations of the primitive) is never entered backwards either."""
    a = np.asarray(transmat, dtype=float)
    ends = (np.diagonal(a, axis1=-2, axis2=-1) >= 1.0 - 1e-9).astype(float)
    chain = _chains(a)
    # Each chain's absorbing states if it has any, else the whole chain; one unit of mass per live chain.
    start = np.where(np.einsum("...ij,...j->...i", chain, ends) > 0, ends, 1.0)
    start = start / np.einsum("...ij,...j->...i", chain, start)
    if startprob is not None:
        start = start * (np.einsum("...ij,...j->...i", chain, np.asarray(startprob, dtype=float)) > 0)
    return start / start.sum(axis=-1, keepdims=True)


def reversed_database(db: MotionDatabase) -> MotionDatabase:
    """The database of clips played backwards (module docstring)."""
    db.validate()
    out = copy.copy(db)
    out.means_ = db.means_ * _REVERSAL_SIGN
    out.covars_ = db.covars_.copy()
    out.transmat_ = reversed_transitions(db.transmat_)
    out.startprob_ = reversed_start(db.transmat_, db.startprob_)
    return out


def reversed_model(model: EngineModel) -> EngineModel:
    """The engine's model of clips played backwards: the reversed database, its point distributions with
    every velocity mean negated (exact, module docstring)."""
    d = model.dists
    dists = replace(d, vel=-d.vel, base_linear=-d.base_linear, base_angular=-d.base_angular)
    return replace(model, db=reversed_database(model.db), dists=dists, db_means=model.db_means * _REVERSAL_SIGN)


def reversed_flows(flows: list[np.ndarray]) -> list[np.ndarray]:
    """The flows of a clip played backwards, in reversed order: element ``s`` is the reversed clip's frame
    ``s``, time ``T - 1 - s``: the forward frame's flows with their velocities negated (module docstring)."""
    out = []
    for f in flows[::-1]:
        f = np.asarray(f, dtype=float).reshape(-1, 4)
        out.append(np.concatenate([f[:, :2], -f[:, 2:]], axis=1))
    return out
