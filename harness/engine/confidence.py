"""Class probabilities that mean what they say: the calibration of the engine's class posterior (issue 25).

The tracks' evidence sums the log-likelihood of every flow of every frame as if each were independent. They
are not (a body's flows move together, and the engine's pose is an estimate), so the evidence gap between two
classes grows tens of nats per second of clip and the raw posterior says 1.00 to a wrong answer as readily as
to a right one. The calibrated posterior of a raw log posterior ``l (C,)``

    p(c) = (1 - eps) softmax((l + b) / tau)_c + eps / C

tempers the evidence by a temperature ``tau`` (the evidence's effective share of independent information is
``1 / tau``) and keeps a floor ``eps`` for what the evidence cannot see (a pose search that failed: the true class
then trails by hundreds of nats, which no temperature can bring back). Both are monotone, so the most probable
class, and every accuracy, is unchanged. The bias ``b`` is zero but for a database's background class
(``unknown``: "none of these"), which it weighs against the primitives: its log prior odds, so that the answer
``unknown`` wins as often as it should. ``tau``, ``eps`` (and ``b``) minimise the negative log-likelihood of the
true class over development runs, motions of no primitive counting as ``unknown`` (``fit``;
``benchmarks/posterior_calibration.py``).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize
from scipy.special import log_softmax, logsumexp

from harness.errors import EngineError


def calibrated(log_posterior: np.ndarray, temperature: float, floor: float, bias: np.ndarray | None = None
               ) -> np.ndarray:
    """The calibrated posterior (module docstring) of raw log posteriors ``(..., C)`` (``-inf`` allowed for a
    class no track holds); ``bias`` ``(C,)``: each class's log prior odds (None: none)."""
    if not (temperature > 0 and 0 <= floor < 1):
        raise EngineError(f"posterior calibration needs temperature > 0 and floor in [0, 1), got {temperature}, "
                          f"{floor}")
    log_posterior = np.asarray(log_posterior, dtype=float)
    if bias is not None:
        log_posterior = log_posterior + np.asarray(bias, dtype=float)
    C = log_posterior.shape[-1]
    return (1.0 - floor) * np.exp(log_softmax(log_posterior / temperature, axis=-1)) + floor / C


def class_bias(classes, unknown_bias: float) -> np.ndarray | None:
    """``(C,)`` the calibration's bias for these classes: ``unknown_bias`` at the background class, else zero
    (None when the classes have no background)."""
    from harness.engine.database import UNKNOWN

    classes = list(np.asarray(classes).astype(str))
    if UNKNOWN not in classes:
        return None
    return np.where(np.asarray(classes) == UNKNOWN, float(unknown_bias), 0.0)


def log_true(log_posterior: np.ndarray, true: np.ndarray, temperature: float, floor: float,
             bias: np.ndarray | None = None) -> np.ndarray:
    """``log p(true class)`` of each row ``(N, C)`` under the calibration, in log space (no underflow)."""
    log_posterior = np.asarray(log_posterior, dtype=float)
    if bias is not None:
        log_posterior = log_posterior + bias
    C = log_posterior.shape[-1]
    tempered = log_softmax(log_posterior / temperature, axis=-1)[np.arange(len(true)), true]
    if floor == 0:
        return tempered
    return np.logaddexp(np.log1p(-floor) + tempered, np.log(floor / C))


def fit(log_posterior: np.ndarray, true: np.ndarray, unknown: int | None = None) -> tuple[float, float, float]:
    """``(temperature, floor, bias)`` minimising the mean negative log-likelihood of the true classes ``(N,)``
    under raw log posteriors ``(N, C)`` (searched over log temperature in [log 0.1, log 1000] and logit floor);
    with ``unknown`` (the background class's column) also the bias of that class, else a bias of 0."""
    log_posterior = np.asarray(log_posterior, dtype=float)
    true = np.asarray(true, dtype=int)
    if log_posterior.ndim != 2 or len(true) != len(log_posterior) or len(true) < 2:
        raise EngineError(f"fit needs log posteriors (N >= 2, C) and N true classes, got {log_posterior.shape} "
                          f"and {true.shape}")
    # -inf (no track held the class) is kept finite for the optimiser; any value this far down is e^-1e4.
    log_posterior = np.maximum(log_posterior - logsumexp(log_posterior, axis=1, keepdims=True), -1e4)

    C = log_posterior.shape[1]

    def bias_of(x):
        return None if unknown is None else np.where(np.arange(C) == unknown, x[2], 0.0)

    def loss(x):
        tau = np.exp(np.clip(x[0], np.log(0.1), np.log(1000.0)))
        eps = 1.0 / (1.0 + np.exp(-x[1]))
        return -np.mean(log_true(log_posterior, true, tau, eps, bias_of(x)))

    starts = [(np.log(t), f) + (() if unknown is None else (b,)) for t in (1.0, 10.0, 100.0) for f in (-8.0, -3.0)
              for b in ((0.0,) if unknown is None else (-30.0, 0.0, 30.0))]
    best = min((minimize(loss, s, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-7}) for s in starts),
               key=lambda r: r.fun)
    return (float(np.exp(np.clip(best.x[0], np.log(0.1), np.log(1000.0)))), float(1.0 / (1.0 + np.exp(-best.x[1]))),
            0.0 if unknown is None else float(best.x[2]))
