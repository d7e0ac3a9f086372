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

import numba
import numpy as np

from harness.engine.transform import ImageDistributions

_GATE = 60.0   # squared Mahalanobis distance in position beyond which a point's term is taken as zero


@numba.njit(cache=True)
def _densities(flows, pix, pix_icov, flow, flow_icov, log_norm, dens):
    """``dens[m, p]``: the Gaussian density of flow ``m`` under point ``p`` of one hypothesis (position and
    velocity), zero beyond the position gate or for an invisible point (``log_norm = -inf``)."""
    M, P = dens.shape
    for m in range(M):
        u, v, du, dv = flows[m, 0], flows[m, 1], flows[m, 2], flows[m, 3]
        for p in range(P):
            dens[m, p] = 0.0
            c = log_norm[p]
            if c == -np.inf:
                continue
            a = u - pix[p, 0]
            b = v - pix[p, 1]
            d2 = pix_icov[p, 0] * a * a + 2.0 * pix_icov[p, 1] * a * b + pix_icov[p, 2] * b * b
            if d2 > _GATE:
                continue
            a = du - flow[p, 0]
            b = dv - flow[p, 1]
            d2 += flow_icov[p, 0] * a * a + 2.0 * flow_icov[p, 1] * a * b + flow_icov[p, 2] * b * b
            dens[m, p] = np.exp(c - 0.5 * d2)


@numba.njit(cache=True)
def _mixture_weights(dens, prior, p_in, p_out, iterations, smoothing, weight, mass):
    """The points' mixture weights: ``prior`` (visibility, normalised) adapted by ``iterations`` EM steps to
    the flows, shrunk towards the prior by ``smoothing`` pseudo-flows. Points that explain no flow (hidden
    by an obstacle the engine cannot know of) give their mass to the points that do."""
    M, P = dens.shape
    for p in range(P):
        weight[p] = prior[p]
    for _ in range(iterations):
        for p in range(P):
            mass[p] = 0.0
        for m in range(M):
            total = 0.0
            for p in range(P):
                total += weight[p] * dens[m, p]
            denom = p_in * total + p_out
            if denom <= 0.0:
                continue
            for p in range(P):
                mass[p] += p_in * weight[p] * dens[m, p] / denom
        norm = 0.0
        for p in range(P):
            norm += mass[p]
        for p in range(P):
            weight[p] = (mass[p] + smoothing * prior[p]) / (norm + smoothing)


@numba.njit(cache=True)
def _prior(log_norm, visibility, prior):
    """Visibility-proportional prior weights; returns False when no point is visible."""
    total = 0.0
    for p in range(len(prior)):
        prior[p] = visibility[p] if log_norm[p] > -np.inf else 0.0
        total += prior[p]
    if total <= 0.0:
        return False
    for p in range(len(prior)):
        prior[p] /= total
    return True


@numba.njit(cache=True)
def _flow_loglik_kernel(flows, pix, pix_icov, flow, flow_icov, log_norm, visibility, log_in, log_out,
                        weight_iterations, smoothing):
    H, P = log_norm.shape
    M = flows.shape[0]
    out = np.empty((H, M))
    dens = np.zeros((M, P))
    weight = np.empty(P)
    mass = np.empty(P)
    prior = np.empty(P)
    p_in = np.exp(log_in)
    p_out = np.exp(log_out)
    for h in range(H):
        if not _prior(log_norm[h], visibility[h], prior):
            for m in range(M):
                out[h, m] = log_out
            continue
        _densities(flows, pix[h], pix_icov[h], flow[h], flow_icov[h], log_norm[h], dens)
        _mixture_weights(dens, prior, p_in, p_out, weight_iterations, smoothing, weight, mass)
        for m in range(M):
            total = 0.0
            for p in range(P):
                total += weight[p] * dens[m, p]
            if total > 0.0:
                inlier = log_in + np.log(total)
                hi = max(inlier, log_out)
                out[h, m] = hi + np.log1p(np.exp(min(inlier, log_out) - hi))
            else:
                out[h, m] = log_out
    return out


@numba.njit(cache=True)
def _responsibilities_kernel(flows, pix, pix_icov, flow, flow_icov, log_norm, visibility, log_in, log_out,
                             weight_iterations, smoothing):
    P = log_norm.shape[0]
    M = flows.shape[0]
    resp = np.zeros((M, P))
    prior = np.empty(P)
    if not _prior(log_norm, visibility, prior):
        return resp
    dens = np.zeros((M, P))
    weight = np.empty(P)
    mass = np.empty(P)
    p_in = np.exp(log_in)
    p_out = np.exp(log_out)
    _densities(flows, pix, pix_icov, flow, flow_icov, log_norm, dens)
    _mixture_weights(dens, prior, p_in, p_out, weight_iterations, smoothing, weight, mass)
    for m in range(M):
        total = 0.0
        for p in range(P):
            total += weight[p] * dens[m, p]
        denom = p_in * total + p_out
        for p in range(P):
            resp[m, p] = p_in * weight[p] * dens[m, p] / denom
    return resp


def _inverse_2x2(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Packed inverses ``(..., 3)`` as ``[a, b, c]`` of ``[[a, b], [b, c]]`` and log-determinants."""
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    det = a * c - b * b
    return np.stack([c / det, -b / det, a / det], axis=-1), np.log(det)


def _packed(flows: np.ndarray, img: ImageDistributions, noise_px: float, fps: float, width: int, height: int,
            outlier_prob: float, max_flow: float | None) -> tuple:
    """The kernels' arguments: flows, packed inverse covariances, log normalisers (``-inf`` for invisible
    points), visibility, and the log inlier and outlier terms."""
    flows = np.ascontiguousarray(flows, dtype=float).reshape(-1, 4)
    if max_flow is None:
        max_flow = 0.25 * max(width, height) * fps   # a quarter of the image per frame
    eye = np.eye(2)
    pix_icov, pix_logdet = _inverse_2x2(img.pix_cov + noise_px**2 * eye)
    flow_icov, flow_logdet = _inverse_2x2(img.flow_cov + 2.0 * (noise_px * fps) ** 2 * eye)
    log_norm = -2.0 * np.log(2 * np.pi) - 0.5 * (pix_logdet + flow_logdet)
    log_norm = np.where(img.visibility > 0, log_norm, -np.inf)
    log_out = np.log(outlier_prob) - np.log(width * height) - np.log(np.pi * max_flow**2)
    log_in = np.log1p(-outlier_prob)
    return (flows, np.ascontiguousarray(img.pix), np.ascontiguousarray(pix_icov), np.ascontiguousarray(img.flow),
            np.ascontiguousarray(flow_icov), np.ascontiguousarray(log_norm),
            np.ascontiguousarray(img.visibility, dtype=float), log_in, log_out)


def flow_log_likelihoods(flows: np.ndarray, img: ImageDistributions, noise_px: float, fps: float,
                         width: int, height: int, outlier_prob: float = 0.05, max_flow: float | None = None,
                         weight_iterations: int = 0, smoothing: float = 0.0) -> np.ndarray:
    """``(H, M)`` log-likelihood of each flow ``(M, 4)`` under each hypothesis (see the module docstring).

    Hypotheses with no visible point explain every flow as an outlier. ``weight_iterations`` EM steps adapt
    the mixture weights of the model points to the flows (``smoothing``: pseudo-flows spread by visibility).
    """
    return _flow_loglik_kernel(*_packed(flows, img, noise_px, fps, width, height, outlier_prob, max_flow),
                               int(weight_iterations), float(smoothing))


def tempered(per_flow: np.ndarray, n_eff: float) -> np.ndarray:
    """Frame log-likelihood per hypothesis ``(H,)`` from per-flow values ``(H, M)``: ``min(M, n_eff)/M`` times
    their sum; zero for an empty frame."""
    M = per_flow.shape[1]
    if M == 0:
        return np.zeros(per_flow.shape[0])
    return per_flow.sum(axis=1) * (min(M, n_eff) / M)


def responsibilities(flows: np.ndarray, img: ImageDistributions, noise_px: float, fps: float, width: int,
                     height: int, outlier_prob: float = 0.05, max_flow: float | None = None,
                     weight_iterations: int = 0, smoothing: float = 0.0) -> np.ndarray:
    """For one hypothesis: ``(M, P)`` posterior probability that flow ``m`` comes from model point ``p``
    (rows sum to one minus the flow's outlier probability), under the same gate, visibility and adapted
    weights as ``flow_log_likelihoods`` (the same kernel code)."""
    args = _packed(flows, img, noise_px, fps, width, height, outlier_prob, max_flow)
    return _responsibilities_kernel(args[0], *(a[0] for a in args[1:7]), *args[7:], int(weight_iterations),
                                    float(smoothing))
