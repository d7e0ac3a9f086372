"""Likelihood of an unlabeled set of flows under pose/state hypotheses.

Each observed flow ``y = (u, v, du, dv)`` is explained by one of the camera-facing model points or is an
outlier:

    p(y | h) = (1 - eps) * (1 / P_h) sum_{p facing} N(u,v; m_hp, S_hp) N(du,dv; n_hp, V_hp) + eps * U(y)

with ``U`` uniform over the image and over image velocities up to ``max_flow`` px/s. Where part of the body is hidden (by an obstacle or by the body itself), the uniform weights
``1 / P_h`` waste mass on points that produce no flows, which favours hypotheses that squeeze the whole body
into the visible part; a few EM steps on the weights (``weight_iterations``), shrunk towards uniform, let
the hidden points give their mass to the visible ones. The observation noise
(pixels) enters ``S`` as ``sigma^2 I`` and ``V`` as ``2 sigma^2 fps^2 I`` (a flow is a difference of two noisy
positions times fps).

Tempering. Flows are not independent evidence: neighbouring features on one limb share the same model error
(the HMM state is a coarse summary, the model points are not the markers), so the plain sum over flows
makes a frame with 80 flows as decisive as 80 frames and collapses the filter and the recognition onto the
first plausible hypothesis. A frame's log-likelihood is therefore ``(min(M, n_eff) / M) sum_m log p(y_m|h)``:
the mean per-flow log-likelihood counted as at most ``n_eff`` independent observations. An empty frame
contributes zero: no evidence, the belief only moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from harness.engine.transform import ImageDistributions

_GATE = 60.0   # squared Mahalanobis distance in position beyond which a point's term is taken as zero


@numba.njit(cache=True)
def _densities(flows, pix, pix_cov, flow, flow_cov, visibility, pos_var, vel_var, rows, cols, vals):
    """The non-zero Gaussian densities of flows under the points of one hypothesis (position and velocity,
    the observation noise ``pos_var``/``vel_var`` added to each covariance): ``vals[k]`` for flow ``rows[k]``
    and point ``cols[k]``; a pair beyond the position gate, or an invisible point, has none. Returns the count.

    ``flows`` are sorted by ``u``: a pair within the gate has ``du^2 <= gate * S_uu`` (the Mahalanobis distance
    is at least that of ``u`` alone), so each point scans only the flows in that band of columns."""
    P = pix.shape[0]
    us = flows[:, 0]
    n = 0
    for p in range(P):
        if visibility[p] <= 0.0:
            continue
        a, b, c = pix_cov[p, 0, 0] + pos_var, pix_cov[p, 0, 1], pix_cov[p, 1, 1] + pos_var
        det_p = a * c - b * b
        ia, ib, ic = c / det_p, -b / det_p, a / det_p
        fa, fb, fc = flow_cov[p, 0, 0] + vel_var, flow_cov[p, 0, 1], flow_cov[p, 1, 1] + vel_var
        det_f = fa * fc - fb * fb
        ja, jb, jc = fc / det_f, -fb / det_f, fa / det_f
        log_norm = -2.0 * np.log(2.0 * np.pi) - 0.5 * (np.log(det_p) + np.log(det_f))
        u0, v0, du0, dv0 = pix[p, 0], pix[p, 1], flow[p, 0], flow[p, 1]
        reach = np.sqrt(_GATE * a)
        for m in range(np.searchsorted(us, u0 - reach), np.searchsorted(us, u0 + reach, side="right")):
            x = flows[m, 0] - u0
            y = flows[m, 1] - v0
            d2 = ia * x * x + 2.0 * ib * x * y + ic * y * y
            if d2 > _GATE:
                continue
            x = flows[m, 2] - du0
            y = flows[m, 3] - dv0
            d2 += ja * x * x + 2.0 * jb * x * y + jc * y * y
            rows[n] = m
            cols[n] = p
            vals[n] = np.exp(log_norm - 0.5 * d2)
            n += 1
    return n


@numba.njit(cache=True)
def _mixture(rows, cols, vals, n, visibility, held, p_in, p_out, iterations, smoothing, weight, mass, total):
    """The points' mixture weights and each flow's inlier density ``total[m] = sum_p w_p N_mp``.

    The weights start from the visibility (normalised) and are adapted by ``iterations`` EM steps to the
    flows, shrunk towards that prior by ``smoothing`` pseudo-flows: points that explain no flow (hidden by an
    obstacle the engine cannot know of) give their mass to the points that do. Points that are ``held`` (they
    lie where flows have appeared recently, so no obstacle hides them) keep their prior proportions and share
    what the free points leave: a held point without flows keeps its weight, and the hypothesis pays for it."""
    P = len(visibility)
    norm = 0.0
    held_prior = 0.0
    for p in range(P):
        norm += visibility[p]
        if held[p]:
            held_prior += visibility[p]
    for p in range(P):
        weight[p] = visibility[p] / norm
    for it in range(iterations + 1):
        for m in range(len(total)):
            total[m] = 0.0
        for k in range(n):
            total[rows[k]] += weight[cols[k]] * vals[k]
        if it == iterations:
            break
        for p in range(P):
            mass[p] = 0.0
        for k in range(n):
            mass[cols[k]] += p_in * weight[cols[k]] * vals[k] / (p_in * total[rows[k]] + p_out)
        s = 0.0
        for p in range(P):
            s += mass[p]
        free = 0.0
        for p in range(P):
            if not held[p]:
                weight[p] = (mass[p] + smoothing * visibility[p] / norm) / (s + smoothing)
                free += weight[p]
        if held_prior > 0.0:
            for p in range(P):
                if held[p]:
                    weight[p] = (1.0 - free) * visibility[p] / held_prior


@numba.njit(cache=True)
def _work(M, P):
    """Work arrays of one hypothesis: the sparse densities (rows, cols, vals) and the weights, masses and
    inlier densities of ``_mixture``."""
    return (np.empty(M * P, dtype=np.int64), np.empty(M * P, dtype=np.int64), np.empty(M * P), np.empty(P),
            np.empty(P), np.empty(M))


@numba.njit(cache=True)
def _hypothesis(flows, pix, pix_cov, flow, flow_cov, visibility, held, pos_var, vel_var, p_in, p_out,
                weight_iterations, smoothing, work):
    """The densities and the adapted mixture of one hypothesis, in ``work``; returns the number of densities."""
    rows, cols, vals, weight, mass, total = work
    n = _densities(flows, pix, pix_cov, flow, flow_cov, visibility, pos_var, vel_var, rows, cols, vals)
    _mixture(rows, cols, vals, n, visibility, held, p_in, p_out, weight_iterations, smoothing, weight, mass, total)
    return n


@numba.njit(cache=True)
def _flow_loglik_kernel(flows, pix, pix_cov, flow, flow_cov, visibility, held, pos_var, vel_var, log_in, log_out,
                        weight_iterations, smoothing):
    H, P = visibility.shape
    M = flows.shape[0]
    out = np.empty((H, M))
    work = _work(M, P)
    total = work[5]
    p_in = np.exp(log_in)
    p_out = np.exp(log_out)
    for h in range(H):
        if visibility[h].sum() <= 0.0:
            for m in range(M):
                out[h, m] = log_out
            continue
        _hypothesis(flows, pix[h], pix_cov[h], flow[h], flow_cov[h], visibility[h], held[h], pos_var, vel_var, p_in,
                    p_out, weight_iterations, smoothing, work)
        for m in range(M):
            if total[m] > 0.0:
                inlier = log_in + np.log(total[m])
                hi = max(inlier, log_out)
                out[h, m] = hi + np.log1p(np.exp(min(inlier, log_out) - hi))
            else:
                out[h, m] = log_out
    return out


@numba.njit(cache=True)
def _responsibilities_kernel(flows, pix, pix_cov, flow, flow_cov, visibility, held, pos_var, vel_var, log_in,
                             log_out, weight_iterations, smoothing):
    P = visibility.shape[0]
    M = flows.shape[0]
    resp = np.zeros((M, P))
    if visibility.sum() <= 0.0:
        return resp
    work = _work(M, P)
    rows, cols, vals, weight, _, total = work
    p_in = np.exp(log_in)
    p_out = np.exp(log_out)
    n = _hypothesis(flows, pix, pix_cov, flow, flow_cov, visibility, held, pos_var, vel_var, p_in, p_out,
                    weight_iterations, smoothing, work)
    for k in range(n):
        m, p = rows[k], cols[k]
        resp[m, p] = p_in * weight[p] * vals[k] / (p_in * total[m] + p_out)
    return resp


@dataclass(frozen=True)
class FlowModel:
    """The observation model's settings: pixel noise ``noise_px``, frame rate, image size, the outlier
    probability, the largest image speed of the uniform outlier term (px/s; None: a quarter of the image per
    frame), and the EM steps and pseudo-flows of the adapted mixture weights."""

    noise_px: float
    fps: float
    width: int
    height: int
    outlier_prob: float = 0.05
    max_flow: float | None = None
    weight_iterations: int = 0
    smoothing: float = 0.0


def _prepared(flows: np.ndarray, img: ImageDistributions, model: FlowModel, held: np.ndarray | None) -> tuple:
    """The kernels' arguments: the flows sorted by ``u`` and their order, the projected distributions, which
    points are held, and the scalars (observation noise's position and velocity variances, log inlier and
    outlier terms, EM steps, pseudo-flows)."""
    flows = np.ascontiguousarray(flows, dtype=float).reshape(-1, 4)
    order = np.argsort(flows[:, 0], kind="stable")
    max_flow = 0.25 * max(model.width, model.height) * model.fps if model.max_flow is None else model.max_flow
    log_out = np.log(model.outlier_prob) - np.log(model.width * model.height) - np.log(np.pi * max_flow**2)
    log_in = np.log1p(-model.outlier_prob)
    dists = (np.ascontiguousarray(img.pix), np.ascontiguousarray(img.pix_cov), np.ascontiguousarray(img.flow),
             np.ascontiguousarray(img.flow_cov), np.ascontiguousarray(img.visibility, dtype=float))
    held = (np.zeros(img.visibility.shape, dtype=np.bool_) if held is None
            else np.ascontiguousarray(np.broadcast_to(held, img.visibility.shape), dtype=np.bool_))
    scalars = (float(model.noise_px**2), float(2.0 * (model.noise_px * model.fps) ** 2), log_in, log_out,
               int(model.weight_iterations), float(model.smoothing))
    return np.ascontiguousarray(flows[order]), order, dists, held, scalars


def flow_log_likelihoods(flows: np.ndarray, img: ImageDistributions, model: FlowModel,
                         held: np.ndarray | None = None) -> np.ndarray:
    """``(H, M)`` log-likelihood of each flow ``(M, 4)`` under each hypothesis (see the module docstring).

    Hypotheses with no visible point explain every flow as an outlier. ``model.weight_iterations`` EM steps
    adapt the mixture weights of the model points to the flows (``model.smoothing``: pseudo-flows spread by
    visibility), except for ``held`` points ``(H, P)`` bool, whose weights keep their prior proportions.
    """
    ordered, order, dists, held, scalars = _prepared(flows, img, model, held)
    out = np.empty((img.visibility.shape[0], len(order)))
    out[:, order] = _flow_loglik_kernel(ordered, *dists, held, *scalars)
    return out


def tempered(per_flow: np.ndarray, n_eff: float) -> np.ndarray:
    """Frame log-likelihood per hypothesis ``(H,)`` from per-flow values ``(H, M)``: ``min(M, n_eff)/M`` times
    their sum; zero for an empty frame."""
    M = per_flow.shape[1]
    if M == 0:
        return np.zeros(per_flow.shape[0])
    return per_flow.sum(axis=1) * (min(M, n_eff) / M)


def responsibilities(flows: np.ndarray, img: ImageDistributions, model: FlowModel,
                     held: np.ndarray | None = None) -> np.ndarray:
    """For one hypothesis: ``(M, P)`` posterior probability that flow ``m`` comes from model point ``p``
    (rows sum to one minus the flow's outlier probability), under the same gate, visibility and adapted
    weights as ``flow_log_likelihoods`` (the same kernel code)."""
    ordered, order, dists, held, scalars = _prepared(flows, img, model, held)
    out = np.empty((len(order), img.visibility.shape[1]))
    out[order] = _responsibilities_kernel(ordered, *(a[0] for a in dists), held[0], *scalars)
    return out
