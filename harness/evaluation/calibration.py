"""Calibration of the final class posterior: whether a probability of 0.9 is right 90% of the time.

(Not the performer's calibration on captures, which is ``harness.motion.calibration``.)

Every recognising run stores its last frame's class posterior (``posterior_final``, ``{class: probability}``,
the posterior whose argmax is ``class_pred``). Over a set of runs ``i = 1..N`` with posteriors ``p_i`` ``(C,)``
and true classes ``y_i``:

- confidence ``c_i = max_k p_ik``; answer ``argmax_k p_ik`` (the first class on a tie, as ``class_pred``);
  ``a_i = 1`` if the answer is ``y_i``;
- **ECE** (expected calibration error, equal-mass bins): the runs sorted by confidence are cut into
  ``ECE_BINS`` bins of as equal run counts as possible, bin ``floor(B r / N)`` for the run of rank ``r``
  (0-based); runs of equal confidence are never split: a tie joins the bin of its lowest-ranked member, so
  there may be fewer, unequal bins (and with fewer runs than bins each run is its own bin).
  ``ECE = sum_b (n_b / N) |mean_b(a) - mean_b(c)|``, 0-1;
- **Brier** score over the full posterior: ``mean_i sum_k (p_ik - [k = y_i])^2``, 0 (certain and right) to 2
  (certain and wrong);
- **NLL**: ``mean_i -ln max(p_i,y_i, NLL_FLOOR)`` nats; the floor (``metrics.LOG_P_FLOOR`` = 1e-15, the clip of
  ``log_p_true``) makes a zero probability of the true class cost 34.54 nats instead of infinity, so
  ``NLL = -mean(log_p_true)``;
- **confident_wrong**: the share of wrong answers given with confidence above ``CONFIDENT`` (0.99), 0 when no
  answer is wrong (the count of wrong answers is in the table beside it).

Pure array functions for the mathematics; ``calibration_table`` and ``pooled_calibration`` take the runner's
table (one row per run and method) and return the metrics per condition and method, or pooled over every
condition (what ``metrics.json`` holds). The formulas are also in ``docs/evaluation.md``.
"""

from __future__ import annotations

import ast

import numpy as np
import pandas as pd

from harness.evaluation.metrics import LOG_P_FLOOR, MetricError

ECE_BINS = 10           # equal-mass bins of the expected calibration error
NLL_FLOOR = LOG_P_FLOOR  # a true-class probability of 0 counts as 1e-15: -ln = 34.54 nats
CONFIDENT = 0.99        # "certain": confidence strictly above this
POSTERIOR = "posterior_final"
METRICS = ("ece", "brier", "nll", "confident_wrong")
TABLE_COLUMNS = ("runs", "accuracy", "confidence", "ece", "bins", "brier", "nll", "wrong", "confident_wrong")
POOLED = "all conditions"


# --- the mathematics: arrays in, numbers out --------------------------------------------------------------

def confidence_correct(probs: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Confidence ``(N,)`` (the largest probability) and correctness ``(N,)`` bool (the argmax, first on a tie,
    is the true class) of posteriors ``probs`` ``(N, C)`` and true class indices ``true`` ``(N,)``."""
    probs, true = _checked(probs, true)
    return probs.max(axis=1), np.argmax(probs, axis=1) == true


def equal_mass_bins(conf: np.ndarray, n_bins: int = ECE_BINS) -> np.ndarray:
    """Bin index ``(N,)`` int, ``0..K-1`` with ``K <= min(n_bins, N)`` non-empty bins in increasing confidence.

    Runs sorted by confidence get bin ``floor(n_bins * r / N)`` at rank ``r``, where tied confidences all take
    the rank of the first of them: a tie is never split between bins (splitting it would make the ECE depend
    on the order of the rows), so bins after a large tie may be empty and are dropped.
    """
    conf = np.asarray(conf, dtype=float)
    if n_bins < 1:
        raise MetricError(f"n_bins must be at least 1, got {n_bins}")
    if conf.ndim != 1:
        raise MetricError(f"confidences must be (N,), got {conf.shape}")
    order = np.argsort(conf, kind="stable")
    ranked = conf[order]
    first = np.searchsorted(ranked, ranked, side="left")      # rank of the first member of each tie
    raw = np.empty(len(conf), dtype=int)
    raw[order] = (n_bins * first) // max(len(conf), 1)
    return np.unique(raw, return_inverse=True)[1].reshape(-1)


def reliability(conf: np.ndarray, correct: np.ndarray, n_bins: int = ECE_BINS) -> pd.DataFrame:
    """Per equal-mass bin (``equal_mass_bins``): ``bin``, ``runs``, ``conf_lo``, ``conf_hi`` (its confidence
    range), ``confidence`` (mean) and ``accuracy`` (fraction right). The points of a reliability diagram."""
    conf, correct = np.asarray(conf, dtype=float), np.asarray(correct, dtype=float)
    cols = ["bin", "runs", "conf_lo", "conf_hi", "confidence", "accuracy"]
    if not len(conf):
        return pd.DataFrame(columns=cols)
    b = equal_mass_bins(conf, n_bins)
    n = np.bincount(b)
    return pd.DataFrame({"bin": np.arange(len(n)), "runs": n,
                         "conf_lo": [conf[b == k].min() for k in range(len(n))],
                         "conf_hi": [conf[b == k].max() for k in range(len(n))],
                         "confidence": np.bincount(b, conf) / n, "accuracy": np.bincount(b, correct) / n})[cols]


def ece(conf: np.ndarray, correct: np.ndarray, n_bins: int = ECE_BINS) -> float:
    """Expected calibration error over equal-mass bins: ``sum_b (n_b / N) |accuracy_b - confidence_b|``, 0-1
    (NaN for no runs)."""
    bins = reliability(conf, correct, n_bins)
    if not len(bins):
        return float("nan")
    return float(np.sum(bins["runs"] * np.abs(bins["accuracy"] - bins["confidence"])) / bins["runs"].sum())


def brier(probs: np.ndarray, true: np.ndarray) -> float:
    """Multi-class Brier score ``mean_i sum_k (p_ik - [k = y_i])^2`` of ``(N, C)`` posteriors, 0-2."""
    probs, true = _checked(probs, true)
    onehot = np.zeros_like(probs)
    onehot[np.arange(len(true)), true] = 1.0
    return float(np.mean(np.sum((probs - onehot) ** 2, axis=1))) if len(true) else float("nan")


def nll(probs: np.ndarray, true: np.ndarray, floor: float = NLL_FLOOR) -> float:
    """Mean negative log-likelihood of the true class, nats: ``mean_i -ln max(p_i,y_i, floor)``."""
    probs, true = _checked(probs, true)
    if not len(true):
        return float("nan")
    return float(np.mean(-np.log(np.maximum(probs[np.arange(len(true)), true], floor))))


def confident_wrong(conf: np.ndarray, correct: np.ndarray, threshold: float = CONFIDENT) -> float:
    """Share of the wrong answers given with confidence above ``threshold`` (0 when none is wrong)."""
    conf, correct = np.asarray(conf, dtype=float), np.asarray(correct, dtype=bool)
    wrong = ~correct
    return float(np.sum(conf[wrong] > threshold) / wrong.sum()) if wrong.any() else 0.0


def scores(probs: np.ndarray, true: np.ndarray, n_bins: int = ECE_BINS) -> dict:
    """Every calibration number of one set of runs: ``TABLE_COLUMNS`` (``bins``: non-empty ECE bins, ``wrong``:
    wrong answers)."""
    conf, correct = confidence_correct(probs, true)
    return {"runs": len(conf), "accuracy": float(correct.mean()) if len(conf) else float("nan"),
            "confidence": float(conf.mean()) if len(conf) else float("nan"),
            "ece": ece(conf, correct, n_bins), "bins": int(len(reliability(conf, correct, n_bins))),
            "brier": brier(probs, true), "nll": nll(probs, true), "wrong": int((~correct).sum()),
            "confident_wrong": confident_wrong(conf, correct)}


def _checked(probs: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    probs, true = np.asarray(probs, dtype=float), np.asarray(true, dtype=int)
    if probs.ndim != 2 or true.shape != (len(probs),):
        raise MetricError(f"posteriors must be (N, C) with N true classes, got {probs.shape} and {true.shape}")
    if len(probs) and (probs.min() < 0 or np.abs(probs.sum(axis=1) - 1.0).max() > 1e-6
                       or true.min() < 0 or true.max() >= probs.shape[1]):
        raise MetricError("posteriors must be probabilities summing to one and true classes indices into them")
    return probs, true


# --- from the runner's table -----------------------------------------------------------------------------

def _posterior(value) -> dict:
    """A row's ``posterior_final``: a dict from the journal, its ``repr`` when read back from ``runs.csv``."""
    if isinstance(value, str):
        value = ast.literal_eval(value) if value.strip() else {}
    return value if isinstance(value, dict) else {}


def posteriors(rows: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], pd.DataFrame]:
    """The final posteriors of the rows that have one: ``probs`` ``(N, C)``, true class indices ``(N,)``, the
    classes (every class named in the rows, first appearance first; a class absent from a run's database has
    probability 0 there) and the rows used (rows without a posterior, a method that does not recognise or a
    run where nothing was seen, are left out)."""
    if POSTERIOR not in rows or not len(rows):
        return np.zeros((0, 0)), np.zeros(0, dtype=int), (), rows.iloc[0:0]
    post = [_posterior(v) for v in rows[POSTERIOR]]
    keep = np.array([len(p) > 0 for p in post], dtype=bool)
    post, used = [p for p, k in zip(post, keep) if k], rows[keep]
    classes = tuple(dict.fromkeys(c for p in post for c in p))
    index = {c: k for k, c in enumerate(classes)}
    probs = np.zeros((len(post), len(classes)))
    for i, p in enumerate(post):
        probs[i, [index[c] for c in p]] = list(p.values())
    missing = sorted(set(used["class_true"]) - set(classes))
    if missing:
        raise MetricError(f"true class {missing[0]!r} has no probability in any posterior_final")
    true = np.array([index[c] for c in used["class_true"]], dtype=int)
    return probs, true, classes, used


def calibration_table(rows: pd.DataFrame, swept: list[str] | tuple[str, ...] = (), n_bins: int = ECE_BINS
                      ) -> pd.DataFrame:
    """One row per condition and recognising method (order of first appearance): condition, swept keys,
    method, then ``TABLE_COLUMNS``; with several conditions, also one row per method over all of them
    (condition ``all conditions``, swept keys empty)."""
    probs, true, _, used = posteriors(rows)
    cols = ["condition", *swept, "method", *TABLE_COLUMNS]
    if not len(used):
        return pd.DataFrame(columns=cols)
    out = []
    pos = np.arange(len(used))
    groups = used.assign(_i=pos).groupby(["condition", "method"], sort=False)
    for (cond, method), g in groups:
        i = g["_i"].to_numpy()
        out.append({"condition": cond, **{k: g.iloc[0][k] for k in swept}, "method": method,
                    **scores(probs[i], true[i], n_bins)})
    if used["condition"].nunique() > 1:
        for method, g in used.assign(_i=pos).groupby("method", sort=False):
            i = g["_i"].to_numpy()
            out.append({"condition": POOLED, **{k: "" for k in swept}, "method": method,
                        **scores(probs[i], true[i], n_bins)})
    return pd.DataFrame(out, columns=cols)


def reliability_table(rows: pd.DataFrame, n_bins: int = ECE_BINS) -> pd.DataFrame:
    """Per recognising method over every condition: its reliability bins (``reliability``) and its ECE."""
    probs, true, _, used = posteriors(rows)
    out = []
    for method, g in used.assign(_i=np.arange(len(used))).groupby("method", sort=False):
        i = g["_i"].to_numpy()
        conf, correct = confidence_correct(probs[i], true[i])
        out.append(reliability(conf, correct, n_bins).assign(method=method, ece=ece(conf, correct, n_bins)))
    cols = ["method", "bin", "runs", "conf_lo", "conf_hi", "confidence", "accuracy", "ece"]
    return pd.concat(out, ignore_index=True)[cols] if out else pd.DataFrame(columns=cols)


def pooled_calibration(rows: pd.DataFrame, n_bins: int = ECE_BINS) -> dict[str, float]:
    """``{"<method>/<metric>": value}`` of ``METRICS`` over every run of every condition (``metrics.json``)."""
    probs, true, _, used = posteriors(rows)
    out = {}
    for method, g in used.assign(_i=np.arange(len(used))).groupby("method", sort=False):
        i = g["_i"].to_numpy()
        s = scores(probs[i], true[i], n_bins)
        out |= {f"{method}/{m}": s[m] for m in METRICS}
    return out
