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

_GATE = 60.0   # squared Mahalanobis distance in position beyond which a point's term is negligible


@numba.njit(cache=True, fastmath=False)
def _flow_loglik_kernel(flows, pix, pix_icov, flow, flow_icov, log_norm, log_in, log_out, weight_iterations,
                        smoothing):
    H, P = log_norm.shape
    M = flows.shape[0]
    out = np.empty((H, M))
    dens = np.zeros((M, P))
    weight = np.empty(P)
    mass = np.empty(P)
    p_in = np.exp(log_in)
    p_out = np.exp(log_out)
    for h in range(H):
        n_facing = 0
        for p in range(P):
            if log_norm[h, p] > -np.inf:
                n_facing += 1
        for m in range(M):
            u, v, du, dv = flows[m, 0], flows[m, 1], flows[m, 2], flows[m, 3]
            for p in range(P):
                dens[m, p] = 0.0
                c = log_norm[h, p]
                if c == -np.inf:
                    continue
                a = u - pix[h, p, 0]
                b = v - pix[h, p, 1]
                d2 = pix_icov[h, p, 0] * a * a + 2.0 * pix_icov[h, p, 1] * a * b + pix_icov[h, p, 2] * b * b
                if d2 > _GATE:
                    continue
                a = du - flow[h, p, 0]
                b = dv - flow[h, p, 1]
                d2 += flow_icov[h, p, 0] * a * a + 2.0 * flow_icov[h, p, 1] * a * b + flow_icov[h, p, 2] * b * b
                dens[m, p] = np.exp(c - 0.5 * d2)
        for p in range(P):
            weight[p] = 1.0 / max(n_facing, 1) if log_norm[h, p] > -np.inf else 0.0
        # EM on the mixture weights: points that explain no flow (hidden by an obstacle or by the body) lose
        # weight, shrunk towards uniform by `smoothing` pseudo-flows.
        for _ in range(weight_iterations):
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
                if log_norm[h, p] > -np.inf:
                    weight[p] = (mass[p] + smoothing / n_facing) / (norm + smoothing)
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


def _inverse_2x2(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Packed inverses ``(..., 3)`` as ``[a, b, c]`` of ``[[a, b], [b, c]]`` and log-determinants."""
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    det = a * c - b * b
    return np.stack([c / det, -b / det, a / det], axis=-1), np.log(det)


def flow_log_likelihoods(flows: np.ndarray, img: ImageDistributions, noise_px: float, fps: float,
                         width: int, height: int, outlier_prob: float = 0.05, max_flow: float | None = None,
                         weight_iterations: int = 0, smoothing: float = 0.0) -> np.ndarray:
    """``(H, M)`` log-likelihood of each flow ``(M, 4)`` under each hypothesis (see the module docstring).

    Hypotheses with no facing point explain every flow as an outlier. ``weight_iterations`` EM steps adapt
    the mixture weights of the model points to the flows (``smoothing``: pseudo-flows spread uniformly).
    """
    flows = np.ascontiguousarray(flows, dtype=float).reshape(-1, 4)
    if max_flow is None:
        max_flow = 0.25 * max(width, height) * fps   # a quarter of the image per frame
    eye = np.eye(2)
    pix_icov, pix_logdet = _inverse_2x2(img.pix_cov + noise_px**2 * eye)
    flow_icov, flow_logdet = _inverse_2x2(img.flow_cov + 2.0 * (noise_px * fps) ** 2 * eye)
    with np.errstate(divide="ignore"):
        log_norm = -2.0 * np.log(2 * np.pi) - 0.5 * (pix_logdet + flow_logdet)
    log_norm = np.where(img.facing, log_norm, -np.inf)
    log_out = np.log(outlier_prob) - np.log(width * height) - np.log(np.pi * max_flow**2)
    log_in = np.log1p(-outlier_prob)
    return _flow_loglik_kernel(flows, np.ascontiguousarray(img.pix), np.ascontiguousarray(pix_icov),
                               np.ascontiguousarray(img.flow), np.ascontiguousarray(flow_icov),
                               np.ascontiguousarray(log_norm), log_in, log_out, int(weight_iterations),
                               float(smoothing))


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
    (rows sum to one minus the outlier probability), with the same weight adaptation as
    ``flow_log_likelihoods``. Plain numpy: used once per frame by recovery."""
    flows = np.asarray(flows, dtype=float).reshape(-1, 4)
    if max_flow is None:
        max_flow = 0.25 * max(width, height) * fps
    eye = np.eye(2)
    pix_icov, pix_logdet = _inverse_2x2(img.pix_cov[0] + noise_px**2 * eye)
    flow_icov, flow_logdet = _inverse_2x2(img.flow_cov[0] + 2.0 * (noise_px * fps) ** 2 * eye)
    facing = img.facing[0]
    n_facing = max(int(facing.sum()), 1)
    a = flows[:, None, :2] - img.pix[0][None]
    b = flows[:, None, 2:] - img.flow[0][None]
    d2 = (pix_icov[None, :, 0] * a[..., 0] ** 2 + 2 * pix_icov[None, :, 1] * a[..., 0] * a[..., 1]
          + pix_icov[None, :, 2] * a[..., 1] ** 2
          + flow_icov[None, :, 0] * b[..., 0] ** 2 + 2 * flow_icov[None, :, 1] * b[..., 0] * b[..., 1]
          + flow_icov[None, :, 2] * b[..., 1] ** 2)
    log_dens = (-2.0 * np.log(2 * np.pi) - 0.5 * (pix_logdet + flow_logdet))[None] - 0.5 * d2
    log_dens = np.where(facing[None], log_dens, -np.inf)
    log_out = np.log(outlier_prob) - np.log(width * height) - np.log(np.pi * max_flow**2)
    weight = np.where(facing, 1.0 / n_facing, 0.0)
    for it in range(weight_iterations + 1):
        with np.errstate(divide="ignore"):
            log_term = np.log1p(-outlier_prob) + np.log(weight)[None] + log_dens
        full = np.concatenate([log_term, np.full((len(flows), 1), log_out)], axis=1)
        full -= full.max(axis=1, keepdims=True)
        r = np.exp(full)
        r /= r.sum(axis=1, keepdims=True)
        r = r[:, :-1]
        if it < weight_iterations:
            weight = np.where(facing, (r.sum(axis=0) + smoothing / n_facing) / (r.sum() + smoothing), 0.0)
    return r
