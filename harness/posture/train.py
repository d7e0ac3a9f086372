"""Training the bottom-up estimator (``harness.engine.bottom_up``): fit, calibrate, score, export.

The network is scikit-learn's ``MLPRegressor`` (ReLU, Adam, early stopping) on standardised features and
targets; its weights are exported to the engine's ``.npz`` and run there in numpy, so the engine never imports
scikit-learn. The data set's clips are split by clip (never by window, whose neighbours share a clip): the fit
on ``1 - holdout`` of them, the uncertainty on the rest:

- ``residual_std`` ``(N_OUTPUTS,)``: each output's held-out residual std;
- the difficulty head: a ridge regression from the last hidden layer to each output group's log mean squared
  standardised residual (``bottom_up.GROUPS``), shifted so that its scale is calibrated on average over the
  held-out windows (the log of a mean is not the mean of the logs).

``scores`` is what the benchmark compares: errors on held-out clips, in the units a reader knows.
"""

from __future__ import annotations

import json
import time

import numpy as np

from harness.engine import bottom_up
from harness.engine.bottom_up import GROUPS, POSTURE, BottomUpModel, rotation_from_axes

HIDDEN = (256, 256)
ALPHA = 1e-3            # L2 penalty of the network's weights
RIDGE = 1.0             # the difficulty head's penalty
_S_DEPTH = np.diag([1.0, 1.0, -1.0])
_S_BODY = np.diag([1.0, -1.0, 1.0])


def split_by_clip(clips: np.ndarray, holdout: float, seed: int) -> np.ndarray:
    """``(N,)`` bool: the examples whose clip is held out (a share ``holdout`` of the clips, drawn by ``seed``)."""
    ids = np.unique(clips)
    rng = np.random.default_rng(seed)
    held = rng.choice(ids, size=max(1, int(round(holdout * len(ids)))), replace=False)
    return np.isin(clips, held)


def fit(x: np.ndarray, y: np.ndarray, clips: np.ndarray, *, seed: int = 0, holdout: float = 0.15,
        max_iter: int = 200, info: dict | None = None) -> tuple[BottomUpModel, dict]:
    """Fit the estimator on examples ``x`` ``(N, F)``, ``y`` ``(N, N_OUTPUTS)`` of clips ``clips`` ``(N,)``;
    returns the model and its held-out scores (``scores``, with the training time)."""
    from sklearn.neural_network import MLPRegressor

    held = split_by_clip(clips, holdout, seed)
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    x_mean, x_std = x[~held].mean(axis=0), x[~held].std(axis=0) + 1e-6
    y_mean, y_std = y[~held].mean(axis=0), y[~held].std(axis=0) + 1e-9
    net = MLPRegressor(hidden_layer_sizes=HIDDEN, alpha=ALPHA, batch_size=256, learning_rate_init=1e-3,
                       max_iter=max_iter, early_stopping=True, n_iter_no_change=8, random_state=seed)
    t0 = time.perf_counter()
    net.fit((x[~held] - x_mean) / x_std, (y[~held] - y_mean) / y_std)
    seconds = time.perf_counter() - t0
    model = BottomUpModel([w.copy() for w in net.coefs_], [b.copy() for b in net.intercepts_], x_mean=x_mean,
                          x_std=x_std, y_mean=y_mean, y_std=y_std, residual_std=np.ones(bottom_up.N_OUTPUTS),
                          scale_w=np.zeros((HIDDEN[-1], len(GROUPS))), scale_b=np.zeros(len(GROUPS)))
    h, pred = model.hidden_and_outputs(x[held])
    resid = y[held] - pred
    model.residual_std = resid.std(axis=0) + 1e-9
    # The difficulty head: log mean squared standardised residual per group, ridge on the hidden layer.
    z2 = (resid / model.residual_std) ** 2
    target = np.stack([np.log(z2[:, part].mean(axis=1) + 1e-6) for part in GROUPS.values()], axis=1)
    hc = h - h.mean(axis=0)
    w = np.linalg.solve(hc.T @ hc + RIDGE * len(h) * np.eye(h.shape[1]), hc.T @ (target - target.mean(axis=0)))
    b = target.mean(axis=0) - h.mean(axis=0) @ w
    mean_z2 = np.stack([z2[:, part].mean(axis=1) for part in GROUPS.values()], axis=1)
    b += np.log(np.mean(mean_z2 / np.exp(h @ w + b), axis=0))     # calibrated on average
    model.scale_w, model.scale_b = w, b
    result = scores(model, x[held], y[held]) | {"train_s": round(seconds, 1), "epochs": int(net.n_iter_),
                                                "examples": int((~held).sum()), "held_out": int(held.sum())}
    model.info = json.dumps((info or {}) | {"scores": result}, sort_keys=True)
    return model, result


def twin_rotation(rot: np.ndarray) -> np.ndarray:
    """``S R S_b`` of rotations ``(..., 3, 3)``."""
    return _S_DEPTH @ rot @ _S_BODY


def rotation_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) of ``a b^T`` for rotations ``(N, 3, 3)``."""
    c = (np.einsum("nij,nij->n", a, b) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def heading_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle (rad) between the base's forward axes projected on the camera's x-z plane (the heading seen
    by a level camera)."""
    fa, fb = a[:, [0, 2], 0], b[:, [0, 2], 0]
    ang = np.arctan2(fa[:, 1], fa[:, 0]) - np.arctan2(fb[:, 1], fb[:, 0])
    return np.abs((ang + np.pi) % (2 * np.pi) - np.pi)


def scores(model: BottomUpModel, x: np.ndarray, y: np.ndarray) -> dict:
    """Held-out scores: the rotation and heading errors up to the twin (deg, mean and median), the angles' rms
    error up to the twin (rad, the twin's posture mirrored), the rates' (rad/s), the base velocities' (m/s),
    the depth's relative error (median of ``|z_est / z - 1|``), and the calibration of the angles' std (the
    mean squared standardised residual, 1 when calibrated)."""
    from harness.engine.features import mirror_features

    pred, std = model.predict(x)
    r_est, r_true = rotation_from_axes(pred[:, bottom_up.ROT]), rotation_from_axes(y[:, bottom_up.ROT])
    direct = rotation_angle(r_est, r_true)
    mirrored = rotation_angle(r_est, twin_rotation(r_true))
    twin = mirrored < direct
    rot_err = np.minimum(direct, mirrored)
    head = np.where(twin, heading_error(r_est, twin_rotation(r_true)), heading_error(r_est, r_true))
    feat_true = np.where(twin[:, None], mirror_features(y[:, POSTURE]), y[:, POSTURE])
    d = pred[:, POSTURE] - feat_true
    angles, rates, base = d[:, :50], d[:, 50:100], d[:, 100:]
    z2 = (angles / std[:, 9:59]) ** 2
    return {"rotation_deg": round(float(np.rad2deg(rot_err.mean())), 2),
            "rotation_median_deg": round(float(np.rad2deg(np.median(rot_err))), 2),
            "heading_deg": round(float(np.rad2deg(head.mean())), 2),
            "heading_median_deg": round(float(np.rad2deg(np.median(head))), 2),
            "angles_rms_rad": round(float(np.sqrt(np.mean(angles**2))), 4),
            "rates_rms_rad_s": round(float(np.sqrt(np.mean(rates**2))), 3),
            "base_velocity_rms": round(float(np.sqrt(np.mean(base**2))), 3),
            "depth_rel_median": round(float(np.median(np.abs(np.exp(pred[:, 6] - y[:, 6]) - 1))), 4),
            "angles_z2": round(float(z2.mean()), 3)}
