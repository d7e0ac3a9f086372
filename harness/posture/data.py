"""The bottom-up estimator's training data: harness-simulated clips, each window's features and targets.

Every clip is a motion (a procedural demonstration by a subject no test or database uses, or a capture row of the
capture library's *development* groups) played in a random scene: a camera at a random distance, azimuth and
elevation, a random marker count and placement, a random obstacle of a random amount, pixel noise and a scaled
subject at random. Never a reported seed's scene and never a report group's capture: the report groups
(docs/captures.md, "Development and report groups") are left out by ``DEVELOPMENT``, and the scenes are drawn
from their own seed sequence (``clip_spec``), not from any scenario's.

``clip_windows`` turns a simulated clip into the estimator's examples: for every frame whose flows the engine
could use, the window's features (``engine.bottom_up.window_features``) and the targets
(``engine.bottom_up.targets``) of the true pose and posture features.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from harness.body import nominal_body
from harness.engine import bottom_up
from harness.engine.features import motion_features
from harness.geometry import to_matrix
from harness.motion import Motion
from harness.motion.performer import CLASSES, demonstrations
from harness.scene.simulate import simulate
from harness.scene.spec import (CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneError, SceneSpec,
                                SubjectSpec)

SUBJECT_BASE = 5000            # procedural performers 5000..: the database trains on 0..7, tests use 1000..
# The capture library's development groups (docs/captures.md): CMU subjects and Bandai styles no report is on.
DEVELOPMENT = {"cmu": ("subject", {"1", "2", "9", "13", "124", "135", "141"}),
               "bandai": ("style", {"active", "childish", "feminine", "happy", "masculinity", "normal", "old",
                                    "sad", "youthful"})}
CAPTURES = Path(__file__).resolve().parents[2] / "captures"
CAPTURE_WINDOW_S = 2.5


def clip_spec(rng: np.random.Generator) -> SceneSpec:
    """A random scene: camera 2.5-7 m away at any azimuth, 0-35 degrees above the look-at point; 50-150
    markers; no obstacle (40%), or a low wall, a pillar or boxes hiding up to half of the subject; 0.5-1.5 px of
    noise; a subject scaled by up to 10% with limbs jittered by up to 5%."""
    preset = rng.choice(["none", "none", "low_wall", "low_wall", "pillar", "boxes"])
    amount = 0.0 if preset == "none" else float(rng.uniform(0.1, 0.5))
    return SceneSpec(MarkerSpec(int(rng.integers(50, 151)), int(rng.integers(2**31))),
                     CameraSpec(distance=float(rng.uniform(2.5, 7.0)), azimuth=float(rng.uniform(0, 360)),
                                elevation=float(rng.uniform(0.0, 35.0))),
                     OccluderSpec(preset=str(preset) if amount > 0 else "none", amount=amount,
                                  seed=int(rng.integers(2**31))),
                     ObservationSpec(noise_px=float(rng.uniform(0.5, 1.5))),
                     SubjectSpec(scale=float(rng.uniform(0.9, 1.1)), limb_scale=float(rng.uniform(0.0, 0.05)),
                                 seed=int(rng.integers(2**31))))


def development_captures(fps: float = 30.0) -> list[Motion]:
    """The capture library's rows of the development groups (``DEVELOPMENT``), any class."""
    from harness.motion.captures import load_capture_set

    out = []
    for name, (field, keep) in DEVELOPMENT.items():
        directory = CAPTURES / name
        if directory.is_dir():
            out += [m for m in load_capture_set(directory, fps=fps) if str(getattr(m, field)) in keep]
    return out


def clip_motion(index: int, rng: np.random.Generator, captures: list[Motion], capture_share: float) -> Motion:
    """The motion of clip ``index``: a development capture row's random window of ``CAPTURE_WINDOW_S`` (with
    probability ``capture_share``) or a procedural demonstration of a random class by performer
    ``SUBJECT_BASE + index``, either side."""
    if captures and rng.random() < capture_share:
        m = captures[int(rng.integers(len(captures)))]
        n = int(round(CAPTURE_WINDOW_S * m.fps)) + 1
        if m.n_frames > n:
            start = int(rng.integers(0, m.n_frames - n + 1))
            m = m.slice(start, start + n)
        return m
    label = str(rng.choice(CLASSES))
    return demonstrations(label, 1, rng, fps=30.0, subject=SUBJECT_BASE + index, body=nominal_body(),
                          left=float(rng.uniform(0.0, 1.0)))[0]


def clip_windows(motion: Motion, spec: SceneSpec, rng: np.random.Generator, stride: int = 1
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Simulate one clip and return its examples: features ``(N, N_FEATURES)`` and targets ``(N, N_OUTPUTS)``,
    every ``stride``-th frame the estimator answers at (``window_features`` not None)."""
    obs, truth = simulate(motion, spec, rng, nominal_body())
    observed = motion.replace(qpos=truth.qpos)
    feats = motion_features(observed)
    rots = to_matrix(truth.base_quat_cam)
    xs, ys = [], []
    for t in range(1, len(obs), stride):
        window = obs.flows[max(0, t - bottom_up.WINDOW + 1):t + 1]
        f = bottom_up.window_features(window, obs.intrinsics, obs.fps)
        if f is None:
            continue
        x, centre, scale = f
        xs.append(x)
        ys.append(bottom_up.targets(rots[t], truth.base_pos_cam[t], feats[t], centre, scale, obs.intrinsics))
    if not xs:
        return np.empty((0, bottom_up.N_FEATURES)), np.empty((0, bottom_up.N_OUTPUTS))
    return np.array(xs), np.array(ys)


def make_clip(args: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Worker: clip ``index`` of the data set of ``seed`` (its own generator ``SeedSequence([seed, index])``);
    returns its features, targets and ``(N,)`` the clip index of each example."""
    seed, index, capture_share, stride = args
    rng = np.random.default_rng(np.random.SeedSequence([seed, index]))
    motion = clip_motion(index, rng, _captures() if capture_share > 0 else [], capture_share)
    spec = clip_spec(rng)
    try:
        x, y = clip_windows(motion, spec, rng, stride)
    except SceneError:      # a performer walking into the camera leaves no room for an obstacle: the clip without
        x, y = clip_windows(motion, replace(spec, occluders=OccluderSpec()), rng, stride)
    return x.astype(np.float32), y.astype(np.float32), np.full(len(x), index)


_CAPTURE_CACHE: list[Motion] | None = None


def _captures() -> list[Motion]:
    global _CAPTURE_CACHE
    if _CAPTURE_CACHE is None:
        _CAPTURE_CACHE = development_captures()
    return _CAPTURE_CACHE


def make_dataset(seed: int, clips: int, *, capture_share: float = 0.25, stride: int = 2, jobs: int = 1,
                 progress=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``clips`` clips (``make_clip``), in ``jobs`` processes: features, targets and each example's clip."""
    jobs_args = [(seed, i, capture_share, stride) for i in range(clips)]
    if jobs > 1:
        from multiprocessing import get_context

        with get_context("spawn").Pool(jobs) as pool:
            parts = []
            for part in pool.imap(make_clip, jobs_args, chunksize=4):
                parts.append(part)
                if progress:
                    progress(len(parts))
    else:
        parts = []
        for a in jobs_args:
            parts.append(make_clip(a))
            if progress:
                progress(len(parts))
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] for p in parts]))
