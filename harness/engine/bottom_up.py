"""The bottom-up posture: what a short window of unlabeled flows says about the body before any pose is chosen.

A learned, discriminative estimate (issue 61): from the last ``WINDOW`` frames of flows to a Gaussian over the
posture (50 angles, their rates, the base's linear and angular velocity in the base frame), the base's
orientation relative to the camera *up to the twin*, its depth and its image position. It is evidence that does
not come from the pose it is weighed at, which the monocular flips need (``docs/engine.md``, "Bottom-up
posture"). This module is the inference only: the features of a window (``window_features``), a small network
in numpy (``BottomUpModel``, weights from ``bottom_up.npz``, loaded without pickle) and the decoding of its
output into a ``PostureEstimate``. Training (which simulates with the harness) is ``harness.posture``.

**Normalisation.** A window is described in the current frame's own units: positions about the median of its
flows, divided by the 5-95% range of their image rows ``s`` (px); velocities in ``s`` per frame. So the features
do not depend on where the body is in the image or how far it is; the image centre's ray and ``log(s / f)`` are
given apart, so perspective can still be read.

**Features** (``window_features``): per frame of the window, on a fixed grid over the normalised image, the
Gaussian-kernel density of the flows (summing to one) and their kernel-weighted mean velocity, plus a few
globals. Unlabeled, untracked points give no correspondence between frames; a grid of densities and mean
velocities is invariant to their order and to their number.

**The twin.** Seen nearly orthographically, a pose and its depth-reflected mirrored twin (``track.twin``) give
the same points; a regression target must not average the two. Every target is therefore taken in its
*canonical* form: the one of the pair whose forward axis points towards the camera (base x has a negative
camera z), with the posture mirrored (``features.mirror_features``) when that is the twin. The estimate's
``pose_modes`` are the canonical pose and its twin, each with its own posture.

**Uncertainty.** Each output carries a standard deviation: the network's held-out residual per output,
scaled per window by a second, small head that predicts how hard this window is (its log squared residual per
output group), both fitted on held-out clips.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from harness.engine.features import mirror_features
from harness.errors import EngineError
from harness.pinhole import Intrinsics

MODEL_PATH = Path(__file__).with_name("bottom_up.npz")
WINDOW = 5                      # frames of flows per estimate (the current one and the four before it)
GRID_X = np.linspace(-0.9, 0.9, 7)     # grid centres over the normalised image (body extents about the median)
GRID_Y = np.linspace(-1.0, 1.0, 9)
KERNEL = 0.15                   # the grid kernel's std (body extents)
MIN_FLOWS = 5                   # fewer flows in the current frame: no estimate
MIN_EXTENT_PX = 8.0
N_GLOBAL = 5
N_FEATURES = WINDOW * 3 * len(GRID_X) * len(GRID_Y) + N_GLOBAL
# The output vector: orientation (6: the base's x and y axes in the camera frame), log apparent height (1),
# the base's image offset (2), then the 106 posture features (angles, rates, base velocities).
ROT, LOG_H, OFFSET, POSTURE = slice(0, 6), 6, slice(7, 9), slice(9, 115)
N_OUTPUTS = 115
# Output groups whose difficulty the uncertainty head predicts (one log-variance scale each).
GROUPS = {"rotation": ROT, "depth": slice(6, 7), "offset": OFFSET, "angles": slice(9, 59), "rates": slice(59, 109),
          "base": slice(109, 115)}
_S_DEPTH = np.diag([1.0, 1.0, -1.0])     # depth reflection (camera frame)
_S_BODY = np.diag([1.0, -1.0, 1.0])      # the body's left-right mirror (base frame)


def normalisation(flows: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The current frame's centre ``(2,)`` (median of its flows' positions, px) and scale ``s`` (5-95% range of
    their rows, px), or None with fewer than ``MIN_FLOWS`` flows."""
    flows = np.asarray(flows, dtype=float).reshape(-1, 4)
    if len(flows) < MIN_FLOWS:
        return None
    lo, hi = np.percentile(flows[:, 1], [5, 95])
    return np.median(flows[:, :2], axis=0), max(float(hi - lo), MIN_EXTENT_PX)


def window_features(window: list[np.ndarray], intr: Intrinsics, fps: float) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Features ``(N_FEATURES,)`` of a window of flows (``window``: up to ``WINDOW`` frames ``(M_i, 4)``, oldest
    first, the current frame last; missing frames give zero cells), with the normalisation's centre ``(2,)`` and
    scale (px); None when the current frame has too few flows (``normalisation``)."""
    norm = normalisation(window[-1])
    if norm is None:
        return None
    centre, scale = norm
    frames = [np.empty((0, 4))] * (WINDOW - len(window)) + [np.asarray(f, dtype=float).reshape(-1, 4)
                                                             for f in window[-WINDOW:]]
    gx, gy = np.meshgrid(GRID_X, GRID_Y, indexing="ij")
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)                       # (G, 2)
    out = []
    present = 0
    for f in frames:
        if not len(f):
            out.append(np.zeros(3 * len(grid)))
            continue
        present += 1
        p = (f[:, :2] - centre) / scale
        v = f[:, 2:] / (scale * fps)
        k = np.exp(-0.5 * np.sum((p[:, None, :] - grid[None]) ** 2, axis=2) / KERNEL**2)     # (M, G)
        mass = k.sum(axis=0)
        density = mass / max(mass.sum(), 1e-12)
        mean_v = (k.T @ v) / (mass[:, None] + 0.5)      # shrunk to zero where few flows are
        out.append(np.concatenate([density, mean_v[:, 0], mean_v[:, 1]]))
    ray = (centre - np.array([intr.cx, intr.cy])) / np.array([intr.fx, intr.fy])
    globals_ = np.array([ray[0], ray[1], np.log(scale / intr.fy), np.log(len(frames[-1])), present / WINDOW])
    return np.concatenate(out + [globals_]), centre, scale


def canonical(rot: np.ndarray, features: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """A pose's canonical member of its twin pair (module docstring): camera-from-base rotation ``(3, 3)`` and
    posture features ``(106,)`` as given, or their twin ``S R S_b`` with the mirrored posture when the base's
    forward axis points away from the camera; and whether the twin was taken."""
    if rot[2, 0] > 0:
        return _S_DEPTH @ rot @ _S_BODY, mirror_features(features), True
    return rot, np.asarray(features, dtype=float), False


def targets(rot: np.ndarray, base_pos: np.ndarray, features: np.ndarray, centre: np.ndarray, scale: float,
            intr: Intrinsics) -> np.ndarray:
    """The training target ``(N_OUTPUTS,)`` of one window: the canonical orientation's x and y axes, the log
    apparent height ``log(z s / f_y)`` (m), the base's image offset from the centre in ``s`` and the canonical
    posture features. ``rot`` ``(3, 3)``, ``base_pos`` ``(3,)`` camera frame; ``features`` ``(106,)``."""
    rot_c, feat_c, _ = canonical(rot, features)
    z = base_pos[2]
    pix = np.array([intr.fx * base_pos[0] / z + intr.cx, intr.fy * base_pos[1] / z + intr.cy])
    return np.concatenate([rot_c[:, 0], rot_c[:, 1], [np.log(z * scale / intr.fy)], (pix - centre) / scale, feat_c])


def rotation_from_axes(six: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` from two predicted axes ``(..., 6)`` (x then y), made orthonormal (Gram-Schmidt)."""
    a, b = six[..., :3], six[..., 3:]
    x = a / np.linalg.norm(a, axis=-1, keepdims=True)
    y = b - np.sum(x * b, axis=-1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    return np.stack([x, y, np.cross(x, y)], axis=-1)


def fuse(mean: np.ndarray, var: np.ndarray, other: np.ndarray, other_var: np.ndarray, weight: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """The product of two diagonal Gaussians (a belief's and the estimate's), the second's precision times
    ``weight``: its mean and variance, elementwise."""
    precision = 1.0 / var + weight / other_var
    return (mean / var + weight * other / other_var) / precision, 1.0 / precision


@dataclass(frozen=True)
class PostureEstimate:
    """What one window says (module docstring), in the canonical member of the twin pair.

    rotation ``(3, 3)`` camera from base; position ``(3,)`` m, camera frame (the base's image point at the
    estimated depth); features ``(106,)`` the posture ``[angles, rates, base linear, base angular]`` and
    features_std ``(106,)``; rotation_std (rad, about any axis); log_depth_std (of the depth's log)."""

    rotation: np.ndarray
    position: np.ndarray
    features: np.ndarray
    features_std: np.ndarray
    rotation_std: float
    log_depth_std: float

    def pose_modes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The two poses up to the twin, each with its posture: ``[(rotation, features), (twin rotation, mirrored
        features)]``."""
        return [(self.rotation, self.features),
                (_S_DEPTH @ self.rotation @ _S_BODY, mirror_features(self.features))]

    def posture_near(self, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The posture features ``(106,)`` and their std ``(106,)`` of the mode nearer a pose's rotation
        ``(3, 3)`` (the larger ``trace(R^T R_mode)``): a track at the twin's pose gets the mirrored posture."""
        (r0, f0), (r1, f1) = self.pose_modes()
        near_twin = np.trace(rotation.T @ r1) > np.trace(rotation.T @ r0)
        return (f1, mirror_features(self.features_std)) if near_twin else (f0, self.features_std)


class BottomUpModel:
    """The trained estimator: a multilayer perceptron with ReLU hidden layers on standardised features and
    outputs, its held-out residual std per output, and a linear head on the last hidden layer for each output
    group's log variance scale. Arrays from ``bottom_up.npz`` (``BottomUpModel.load``; ``to_arrays`` writes
    them)."""

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray], *, x_mean: np.ndarray,
                 x_std: np.ndarray, y_mean: np.ndarray, y_std: np.ndarray, residual_std: np.ndarray,
                 scale_w: np.ndarray, scale_b: np.ndarray, info: str = ""):
        if len(weights) != len(biases) or not weights:
            raise EngineError("a bottom-up model needs as many weight matrices as bias vectors, at least one")
        if weights[0].shape[0] != N_FEATURES or weights[-1].shape[1] != N_OUTPUTS:
            raise EngineError(f"a bottom-up model maps {N_FEATURES} features to {N_OUTPUTS} outputs, this one "
                              f"{weights[0].shape[0]} to {weights[-1].shape[1]}")
        self.weights, self.biases = weights, biases
        self.x_mean, self.x_std, self.y_mean, self.y_std = x_mean, x_std, y_mean, y_std
        self.residual_std, self.scale_w, self.scale_b = residual_std, scale_w, scale_b
        self.info = info

    @classmethod
    def load(cls, path: str | Path = MODEL_PATH) -> "BottomUpModel":
        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise EngineError(f"{path}: no bottom-up model (python -m harness train-posture writes it)") from None
        n = int(a["layers"])
        return cls([a[f"w{i}"].astype(float) for i in range(n)], [a[f"b{i}"].astype(float) for i in range(n)],
                   x_mean=a["x_mean"], x_std=a["x_std"], y_mean=a["y_mean"], y_std=a["y_std"],
                   residual_std=a["residual_std"], scale_w=a["scale_w"].astype(float),
                   scale_b=a["scale_b"].astype(float), info=str(a["info"]))

    def to_arrays(self) -> dict:
        """The ``.npz`` contents (weights in single precision: the file ships in the repository)."""
        out = {"layers": np.array(len(self.weights)), "x_mean": self.x_mean, "x_std": self.x_std,
               "y_mean": self.y_mean, "y_std": self.y_std, "residual_std": self.residual_std,
               "scale_w": self.scale_w.astype(np.float32), "scale_b": self.scale_b.astype(np.float32),
               "info": np.array(self.info)}
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            out[f"w{i}"], out[f"b{i}"] = w.astype(np.float32), b.astype(np.float32)
        return out

    def hidden_and_outputs(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The last hidden layer ``(N, H)`` and the outputs ``(N, N_OUTPUTS)`` (in target units) of features
        ``(N, N_FEATURES)``."""
        h = (np.atleast_2d(x) - self.x_mean) / self.x_std
        for w, b in zip(self.weights[:-1], self.biases[:-1]):
            h = np.maximum(h @ w + b, 0.0)
        return h, (h @ self.weights[-1] + self.biases[-1]) * self.y_std + self.y_mean

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Outputs ``(N, N_OUTPUTS)`` and their standard deviations ``(N, N_OUTPUTS)``: the held-out residual
        std of each output times the window's predicted scale of its group."""
        h, y = self.hidden_and_outputs(x)
        log_var = np.clip(h @ self.scale_w + self.scale_b, -4.0, 4.0)       # (N, groups)
        std = np.broadcast_to(self.residual_std, y.shape).copy()
        for g, part in enumerate(GROUPS.values()):
            std[:, part] *= np.exp(0.5 * log_var[:, g:g + 1])
        return y, std

    def estimate(self, window: list[np.ndarray], intr: Intrinsics, fps: float) -> PostureEstimate | None:
        """The estimate of one window of flows (``window_features``), or None when its current frame has too
        few flows."""
        feat = window_features(window, intr, fps)
        if feat is None:
            return None
        x, centre, scale = feat
        y, std = self.predict(x)
        return decode(y[0], std[0], centre, scale, intr)


def decode(y: np.ndarray, std: np.ndarray, centre: np.ndarray, scale: float, intr: Intrinsics) -> PostureEstimate:
    """A ``PostureEstimate`` from one output vector ``(N_OUTPUTS,)`` and its std, with the window's centre and
    scale (px). The rotation's std is the axes' mean std (a small rotation moves a unit axis by its angle)."""
    rot = rotation_from_axes(y[ROT])
    z = np.exp(y[LOG_H]) * intr.fy / scale
    pix = centre + scale * y[OFFSET]
    position = np.array([(pix[0] - intr.cx) * z / intr.fx, (pix[1] - intr.cy) * z / intr.fy, z])
    return PostureEstimate(rot, position, y[POSTURE].copy(), std[POSTURE].copy(), float(np.mean(std[ROT])),
                           float(std[LOG_H]))


@lru_cache(maxsize=2)
def load_model(path: str = str(MODEL_PATH)) -> BottomUpModel:
    """The shipped model, loaded once per process."""
    return BottomUpModel.load(path)
