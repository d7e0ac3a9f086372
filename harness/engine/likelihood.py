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

Recognition may score each flow's velocity given its position instead (``velocity_log_likelihoods``):

    log p(du, dv | u, v, h) = log p(y | h) - log p(u, v | h),
    p(u, v | h) = (1 - eps) sum_{p facing} w_p N(u,v; m_hp, S_hp) + eps U_image

with the same mixture weights ``w_p``: the flows' positions then only say which points they come from, and
the evidence is in how they move. The positions of a standing body's flows are explained by its base pose as
much as by its posture, so a few centimetres of pose error move the positions' evidence between classes by
more than the classes differ (``docs/engine.md``); the velocities given the positions do not carry that.

The densities and the adapted weights are computed in float32 (twice the vector lanes of doubles): a flow's
log-likelihood is within about 1e-5 nats of the double computation on the same float32-rounded flows, and
densities below ``e^-25`` of the outlier density are zero (``_CUT``). Each flow's log is taken in double.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from harness.engine.open_region import OpenMask, is_open
from harness.engine.transform import ImageDistributions
from harness.engine.vector_math import EXP32_MIN, FAST, LOG_MIN, exp32_parts, log_normal

_GATE = 60.0   # squared Mahalanobis distance in position beyond which a point's term is taken as zero
# A density below the outlier density times e^-_CUT is taken as zero: the inlier mixture (weights at most one)
# loses at most that share of the outlier term, a flow's log-likelihood less than e^-25 = 1.4e-11. It keeps the
# float32 densities and their products with the weights clear of subnormal numbers.
_CUT = 25.0

_F = np.float32
_GATE32, _HALF32, _ZERO32, _INF32 = _F(_GATE), _F(0.5), _F(0.0), _F(np.inf)
_EXP32_MAX = _F(88.0)        # exp of float32 overflows above 88.7
_LOG_TWO_PI_SQUARED = 2.0 * np.log(2.0 * np.pi)
_LANES = 8     # the flows are padded to a multiple of this (float32s in a 256-bit register)


@numba.njit(cache=True, fastmath=FAST, error_model="numpy")
def _densities(flows, pix, pix_cov, flow, flow_cov, visibility, pos_var, vel_var, log_cut, points, dens, arg, scale):
    """The Gaussian densities of the flows (``(4, M)`` float32 columns) under the visible points of one
    hypothesis (position and velocity, the observation noise ``pos_var``/``vel_var`` added to each covariance):
    ``dens[i, m]`` for visible point ``i`` (model point ``points[i]``), zero beyond the position gate and below
    ``exp(log_cut)``. Returns the number of visible points; ``arg``, ``scale``: float32 work arrays of ``M``.

    Every flow is scored against every visible point in one dense pass that vectorises (``vector_math``):
    with a few dozen flows, a band of them per point (the flows sorted by ``u``) saves less than its
    bookkeeping costs. Each point's constants are computed in double precision and the pass in float32, with
    twice the lanes: a pixel coordinate below 10^4 is held to 10^-3 px, the Mahalanobis terms to float32's
    unit round-off, and a density to about 1e-4 of itself where it counts (``tests/test_engine_parts.py``).
    The normaliser enters the exponent, so no density is formed below ``exp(log_cut)``."""
    P = pix.shape[0]
    M = flows.shape[1]
    us, vs, dus, dvs = flows[0], flows[1], flows[2], flows[3]
    n = 0
    for p in range(P):
        if visibility[p] <= 0.0:
            continue
        a, b, c = pix_cov[p, 0, 0] + pos_var, pix_cov[p, 0, 1], pix_cov[p, 1, 1] + pos_var
        inv_det_p = 1.0 / (a * c - b * b)
        fa, fb, fc = flow_cov[p, 0, 0] + vel_var, flow_cov[p, 0, 1], flow_cov[p, 1, 1] + vel_var
        inv_det_f = 1.0 / (fa * fc - fb * fb)
        ia, ib, ic = _F(c * inv_det_p), _F(-2.0 * b * inv_det_p), _F(a * inv_det_p)
        ja, jb, jc = _F(fc * inv_det_f), _F(-2.0 * fb * inv_det_f), _F(fa * inv_det_f)
        log_norm = _F(0.5 * np.log(inv_det_p * inv_det_f) - _LOG_TWO_PI_SQUARED)
        u0, v0, du0, dv0 = _F(pix[p, 0]), _F(pix[p, 1]), _F(flow[p, 0]), _F(flow[p, 1])
        row = dens[n]
        # One pass computes the argument and the exponential's polynomial (``exp32_parts``), a second applies the
        # power of two, the gate and the cut: measured 14% faster than filling the arguments first.
        for m in range(M):
            x = us[m] - u0
            y = vs[m] - v0
            d2 = ia * x * x + ib * x * y + ic * y * y
            x = dus[m] - du0
            y = dvs[m] - dv0
            e = log_norm - _HALF32 * (d2 + ja * x * x + jb * x * y + jc * y * y)
            arg[m] = e if d2 <= _GATE32 else -_INF32
            row[m], scale[m] = exp32_parts(min(max(e, EXP32_MIN), _EXP32_MAX))
        for m in range(M):
            row[m] = row[m] * scale[m] if arg[m] >= log_cut else _ZERO32
        points[n] = p
        n += 1
    return n


@numba.njit(cache=True, fastmath=FAST, error_model="numpy")
def _position_densities(flows, pix, pix_cov, pos_var, points, n, dens, arg, scale):
    """The position factor of ``_densities``' densities alone, under the same ``n`` visible points ``points[:n]``
    and gate (float32, as there): ``dens[i, m] = N(u_m, v_m; pix_p, pix_cov_p + pos_var I)`` for
    ``p = points[i]``, zero beyond the gate. ``arg``, ``scale``: float32 work arrays of ``M``."""
    M = flows.shape[1]
    us, vs = flows[0], flows[1]
    for i in range(n):
        p = points[i]
        a, b, c = pix_cov[p, 0, 0] + pos_var, pix_cov[p, 0, 1], pix_cov[p, 1, 1] + pos_var
        inv_det = 1.0 / (a * c - b * b)
        ia, ib, ic = _F(c * inv_det), _F(-2.0 * b * inv_det), _F(a * inv_det)
        norm = _F(np.sqrt(inv_det) / (2.0 * np.pi))
        u0, v0 = _F(pix[p, 0]), _F(pix[p, 1])
        row = dens[i]
        for m in range(M):
            x = us[m] - u0
            y = vs[m] - v0
            d2 = ia * x * x + ib * x * y + ic * y * y
            arg[m] = d2
            mantissa, scale[m] = exp32_parts(-_HALF32 * min(max(d2, _ZERO32), _GATE32))  # padding (NaN): below
            row[m] = norm * mantissa
        for m in range(M):
            row[m] = row[m] * scale[m] if arg[m] <= _GATE32 else _ZERO32


@numba.njit(cache=True, fastmath=FAST, error_model="numpy")
def _mixture(dens, points, n, visibility, held, p_in, p_out, iterations, smoothing, weight, total, inv):
    """The visible points' mixture weights ``weight[:n]`` and each flow's inlier density
    ``total[m] = sum_i w_i N_mi`` (float32, as the densities; ``p_in``, ``p_out`` float32).

    The weights start from the visibility (normalised) and are adapted by ``iterations`` EM steps to the
    flows, shrunk towards that prior by ``smoothing`` pseudo-flows: points that explain no flow (hidden by an
    obstacle the engine cannot know of) give their mass to the points that do. Points that are held (``held[i]``
    for visible point ``i``: they lie where flows have appeared recently, so no obstacle hides them) keep their
    prior proportions and share what the free points leave: a held point without flows keeps its weight, and the
    hypothesis pays for it. ``inv``: work array of ``M``."""
    norm = 0.0
    held_prior = 0.0
    for i in range(n):
        v = visibility[points[i]]
        norm += v
        if held[i]:
            held_prior += v
    for i in range(n):
        weight[i] = visibility[points[i]] / norm
    M = len(total)
    for it in range(iterations + 1):
        for m in range(M):
            total[m] = _ZERO32
        for i in range(n):
            w = weight[i]
            row = dens[i]
            for m in range(M):
                total[m] += w * row[m]
        if it == iterations:
            break
        for m in range(M):
            inv[m] = p_in / (p_in * total[m] + p_out)
        s = 0.0
        for i in range(n):
            acc = _ZERO32
            row = dens[i]
            for m in range(M):
                acc += row[m] * inv[m]
            weight[i] *= acc                    # this step's mass of point i
            s += weight[i]
        free = 0.0
        for i in range(n):
            if not held[i]:
                weight[i] = (weight[i] + smoothing * visibility[points[i]] / norm) / (s + smoothing)
                free += weight[i]
        if held_prior > 0.0:
            for i in range(n):
                if held[i]:
                    weight[i] = (1.0 - free) * visibility[points[i]] / held_prior


@numba.njit(cache=True)
def _work(M, P):
    """float32 work arrays of one hypothesis: the densities and their points (``_densities``), the exponential's
    arguments and powers of two, and the weights, inlier densities and inverses of ``_mixture``; which visible
    points are held (``_hypothesis``)."""
    return (np.empty((P, M), dtype=np.float32), np.empty(P, dtype=np.int64), np.empty(M, dtype=np.float32),
            np.empty(M, dtype=np.float32), np.empty(P, dtype=np.float32), np.empty(M, dtype=np.float32),
            np.empty(M, dtype=np.float32), np.empty(P, dtype=np.bool_))


@numba.njit(cache=True)
def _terms(log_in, log_out, smoothing):
    """The float32 scalars every hypothesis of a kernel call shares: the densities' cut (``_CUT``), the inlier
    and outlier shares and the pseudo-flows of ``_mixture``."""
    return _F(max(log_out - _CUT, EXP32_MIN)), _F(np.exp(log_in)), _F(np.exp(log_out)), _F(smoothing)


@numba.njit(cache=True)
def _hypothesis(flows, pix, pix_cov, flow, flow_cov, visibility, open_cells, inv_cell, pos_var, vel_var, terms,
                weight_iterations, work):
    """The densities and the adapted mixture of one hypothesis, in ``work`` (``terms``: ``_terms``), its visible
    points held where they fall in the open region (``open_region.is_open``; an empty grid: none); returns the
    number of visible points."""
    dens, points, arg, scale, weight, total, inv, held = work
    log_cut, p_in, p_out, smoothing = terms
    n = _densities(flows, pix, pix_cov, flow, flow_cov, visibility, pos_var, vel_var, log_cut, points, dens, arg,
                   scale)
    for i in range(n):
        held[i] = is_open(open_cells, inv_cell, pix[points[i], 0], pix[points[i], 1])
    _mixture(dens, points, n, visibility, held, p_in, p_out, weight_iterations, smoothing, weight, total, inv)
    return n


@numba.njit(cache=True)
def _flow_loglik_kernel(flows, n_flows, pix, pix_cov, flow, flow_cov, visibility, open_cells, inv_cell, pos_var,
                        vel_var, log_in, log_out, weight_iterations, smoothing):
    H, P = visibility.shape
    M = flows.shape[1]
    out = np.empty((H, n_flows))
    work = _work(M, P)
    terms = _terms(log_in, log_out, smoothing)
    for h in range(H):
        n = _hypothesis(flows, pix[h], pix_cov[h], flow[h], flow_cov[h], visibility[h], open_cells, inv_cell, pos_var,
                        vel_var, terms, weight_iterations, work)
        _per_flow(n, work[5], log_in, log_out, out[h])
    return out


@numba.njit(cache=True)
def _velocity_loglik_kernel(flows, n_flows, pix, pix_cov, flow, flow_cov, visibility, open_cells, inv_cell, pos_var,
                            vel_var, log_in, log_out, weight_iterations, smoothing, log_out_position):
    """``_flow_loglik_kernel``'s per-flow values less the positions' own mixture under the same weights (module
    docstring); ``log_out_position``: the log outlier density of a position alone."""
    H, P = visibility.shape
    M = flows.shape[1]
    out = np.empty((H, n_flows))
    work = _work(M, P)
    dens, points, arg, scale, weight, total, _, _ = work
    position = np.empty((P, M), dtype=np.float32)
    total_position = np.empty(M, dtype=np.float32)
    joint, given = np.empty(n_flows), np.empty(n_flows)
    terms = _terms(log_in, log_out, smoothing)
    for h in range(H):
        n = _hypothesis(flows, pix[h], pix_cov[h], flow[h], flow_cov[h], visibility[h], open_cells, inv_cell, pos_var,
                        vel_var, terms, weight_iterations, work)
        _position_densities(flows, pix[h], pix_cov[h], pos_var, points, n, position, arg, scale)
        total_position[:] = _ZERO32
        for i in range(n):
            w = weight[i]
            for m in range(M):
                total_position[m] += w * position[i, m]
        _per_flow(n, total, log_in, log_out, joint)
        _per_flow(n, total_position, log_in, log_out_position, given)
        for m in range(n_flows):
            out[h, m] = joint[m] - given[m]
    return out


@numba.njit(cache=True, fastmath=FAST, error_model="numpy")
def _per_flow(n, total, log_in, log_out, out):
    """``out[m] = log((1 - eps) total[m] + eps U)`` from each flow's inlier density ``total`` (``_mixture``) over
    ``n`` visible points; every flow an outlier when none is visible. The mixture is at least the outlier term,
    a normal double for any camera and outlier share in use, so one vectorising ``log_normal`` takes it (three
    libm calls a flow before, a tenth of the flow kernel's time); below that, the sum of the logs."""
    if n == 0:
        out[:] = log_out
        return
    p_in, p_out = np.exp(log_in), np.exp(log_out)
    if p_out >= LOG_MIN:
        for m in range(len(out)):
            out[m] = log_normal(p_in * np.float64(total[m]) + p_out)
        return
    for m in range(len(out)):
        if total[m] > 0.0:
            inlier = log_in + np.log(np.float64(total[m]))
            hi = max(inlier, log_out)
            out[m] = hi + np.log1p(np.exp(min(inlier, log_out) - hi))
        else:
            out[m] = log_out


@numba.njit(cache=True)
def _responsibilities_kernel(flows, n_flows, pix, pix_cov, flow, flow_cov, visibility, open_cells, inv_cell, pos_var,
                             vel_var, log_in, log_out, weight_iterations, smoothing):
    P = visibility.shape[0]
    M = flows.shape[1]
    resp = np.zeros((n_flows, P))
    work = _work(M, P)
    dens, points, _, _, weight, total, _, _ = work
    p_in = np.exp(log_in)
    p_out = np.exp(log_out)
    n = _hypothesis(flows, pix, pix_cov, flow, flow_cov, visibility, open_cells, inv_cell, pos_var, vel_var,
                    _terms(log_in, log_out, smoothing), weight_iterations, work)
    for i in range(n):
        p = points[i]
        for m in range(n_flows):
            inlier = p_in * np.float64(weight[i]) * np.float64(dens[i, m])
            resp[m, p] = inlier / (p_in * np.float64(total[m]) + p_out)
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


def _prepared(flows: np.ndarray, img: ImageDistributions, model: FlowModel, open_mask: OpenMask | None) -> tuple:
    """The kernels' arguments: the flows as ``(4, M')`` float32 columns with their number ``M`` (``M'`` rounded up
    to a multiple of ``_LANES`` with flows that are nowhere, NaN: their densities are zero, and the kernels' loops
    over flows run without remainders, measured 20% faster at 41 flows), the projected distributions, the open
    region's grid and its inverse cell size (an empty grid without one), and the scalars (observation noise's
    position and velocity variances, log inlier and outlier terms, EM steps, pseudo-flows)."""
    flows = np.ascontiguousarray(flows, dtype=float).reshape(-1, 4)
    max_flow = 0.25 * max(model.width, model.height) * model.fps if model.max_flow is None else model.max_flow
    log_out = np.log(model.outlier_prob) - np.log(model.width * model.height) - np.log(np.pi * max_flow**2)
    log_in = np.log1p(-model.outlier_prob)
    dists = (np.ascontiguousarray(img.pix), np.ascontiguousarray(img.pix_cov), np.ascontiguousarray(img.flow),
             np.ascontiguousarray(img.flow_cov), np.ascontiguousarray(img.visibility, dtype=float))
    # Which points are held is looked up in the kernels, for the visible points only: an (H, P) mask made
    # beforehand for every point cost as much as a tenth of the weighing's kernel.
    region = _NO_REGION if open_mask is None else (np.ascontiguousarray(open_mask.open, dtype=np.bool_),
                                                    1.0 / open_mask.cell)
    scalars = (float(model.noise_px**2), float(2.0 * (model.noise_px * model.fps) ** 2), log_in, log_out,
               int(model.weight_iterations), float(model.smoothing))
    M = len(flows)
    columns = np.full((4, -(-M // _LANES) * _LANES), np.nan, dtype=np.float32)
    columns[:, :M] = flows.T
    return (columns, M), dists, region, scalars


_NO_REGION = (np.zeros((0, 0), dtype=np.bool_), 0.0)    # no point is held


def flow_log_likelihoods(flows: np.ndarray, img: ImageDistributions, model: FlowModel,
                         open_mask: OpenMask | None = None) -> np.ndarray:
    """``(H, M)`` log-likelihood of each flow ``(M, 4)`` under each hypothesis (see the module docstring).

    Hypotheses with no visible point explain every flow as an outlier. ``model.weight_iterations`` EM steps
    adapt the mixture weights of the model points to the flows (``model.smoothing``: pseudo-flows spread by
    visibility), except for the points held by ``open_mask`` (those whose pixel lies in its open region,
    ``OpenMask.held``), whose weights keep their prior proportions.
    """
    columns, dists, region, scalars = _prepared(flows, img, model, open_mask)
    return _flow_loglik_kernel(*columns, *dists, *region, *scalars)


def velocity_log_likelihoods(flows: np.ndarray, img: ImageDistributions, model: FlowModel,
                             open_mask: OpenMask | None = None) -> np.ndarray:
    """``(H, M)`` log-likelihood of each flow's velocity given its position (the module docstring):
    ``flow_log_likelihoods`` less the log density of the flow's position under the same mixture weights, gate
    and outlier share (an outlier's position uniform over the image)."""
    columns, dists, region, scalars = _prepared(flows, img, model, open_mask)
    log_out_position = np.log(model.outlier_prob) - np.log(model.width * model.height)
    return _velocity_loglik_kernel(*columns, *dists, *region, *scalars, log_out_position)


def tempered(per_flow: np.ndarray, n_eff: float) -> np.ndarray:
    """Frame log-likelihood per hypothesis ``(H,)`` from per-flow values ``(H, M)``: ``min(M, n_eff)/M`` times
    their sum; zero for an empty frame."""
    M = per_flow.shape[1]
    if M == 0:
        return np.zeros(per_flow.shape[0])
    return per_flow.sum(axis=1) * (min(M, n_eff) / M)


def responsibilities(flows: np.ndarray, img: ImageDistributions, model: FlowModel,
                     open_mask: OpenMask | None = None) -> np.ndarray:
    """For one hypothesis: ``(M, P)`` posterior probability that flow ``m`` comes from model point ``p``
    (rows sum to one minus the flow's outlier probability), under the same gate, visibility and adapted
    weights as ``flow_log_likelihoods`` (the same kernel code)."""
    columns, dists, region, scalars = _prepared(flows, img, model, open_mask)
    return _responsibilities_kernel(*columns, *(a[0] for a in dists), *region, *scalars)
