"""Interval estimates and paired tests used by the tables. Arrays in, numbers out; randomness injected."""

from __future__ import annotations

import numpy as np
from scipy import stats as _st

N_BOOT = 2000          # bootstrap resamples; the percentile interval's Monte-Carlo error is then ~0.5% of its width
LEVEL = 0.95


def bootstrap_ci(x: np.ndarray, rng: np.random.Generator, n_boot: int = N_BOOT, level: float = LEVEL
                 ) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``x`` (NaN dropped); ``(nan, nan)`` when empty.

    One sample gives a zero-width interval at that value (there is nothing to resample).
    """
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return float("nan"), float("nan")
    means = x[rng.integers(0, len(x), size=(n_boot, len(x)))].mean(axis=1)
    alpha = 0.5 * (1.0 - level)
    lo, hi = np.quantile(means, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


def mcnemar_exact(a: np.ndarray, b: np.ndarray) -> dict:
    """Exact McNemar test of paired 0/1 outcomes ``a``, ``b`` (same runs): a two-sided binomial test of the
    discordant pairs. Returns ``n_pairs``, ``a_only`` (a right, b wrong), ``b_only`` and ``p_value`` (1.0
    when there are no discordant pairs)."""
    a, b = np.asarray(a, dtype=int), np.asarray(b, dtype=int)
    a_only, b_only = int(np.sum((a == 1) & (b == 0))), int(np.sum((a == 0) & (b == 1)))
    n = a_only + b_only
    p = 1.0 if n == 0 else float(_st.binomtest(min(a_only, b_only), n, 0.5).pvalue)
    return {"n_pairs": int(len(a)), "a_only": a_only, "b_only": b_only, "p_value": p}


def wilcoxon_paired(a: np.ndarray, b: np.ndarray) -> dict:
    """Wilcoxon signed-rank test of paired samples (pairs with a NaN dropped). Returns ``n_pairs``,
    ``median_diff`` (median of a - b) and ``p_value`` (NaN with fewer than 2 non-zero differences)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(a) & np.isfinite(b)
    d = a[keep] - b[keep]
    out = {"n_pairs": int(keep.sum()), "median_diff": float(np.median(d)) if len(d) else float("nan"),
           "p_value": float("nan")}
    if np.count_nonzero(d) >= 2:
        out["p_value"] = float(_st.wilcoxon(a[keep], b[keep], zero_method="wilcox").pvalue)
    return out
