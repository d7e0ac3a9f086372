"""Nearest-class check of the procedural performer: is there a recognition problem worth solving?

Each demonstration's 50 joint angles are time-normalised (linearly resampled to ``N_SAMPLES`` instants over
its duration); the class template is the mean of its training demonstrations; a held-out demonstration is
given the class of the nearest template (Euclidean distance, radians). Training and held-out demonstrations
come from disjoint seeds and disjoint subjects. The requirement (docs/performer.md): accuracy well above chance
(at least ``MIN_ACCURACY``) but not perfect (the intended confusable pairs get confused). Used by
``benchmarks/nearest_class.py`` and the performer's tests.
"""

from __future__ import annotations

import numpy as np

from harness.motion.motion import Motion
from harness.motion.performer import CLASSES, demonstrations

MIN_ACCURACY = 0.6      # six times chance (0.1): the classes are separable
N_SAMPLES = 50
TRAIN_SUBJECTS = range(0, 100)          # training performers; held-out ones come from TEST_SUBJECTS
TEST_SUBJECTS = range(500, 600)


def time_normalise(angles: np.ndarray, n: int = N_SAMPLES) -> np.ndarray:
    """Resample ``(T, J)`` to ``(n, J)`` at evenly spaced fractions of the duration (linear)."""
    angles = np.asarray(angles, dtype=float)
    src = np.linspace(0.0, 1.0, len(angles))
    dst = np.linspace(0.0, 1.0, n)
    return np.stack([np.interp(dst, src, angles[:, j]) for j in range(angles.shape[1])], axis=1)


def features(motions: list[Motion], n: int = N_SAMPLES) -> np.ndarray:
    """``(M, n * 50)``: each motion's time-normalised joint angles, flattened."""
    return np.stack([time_normalise(m.angles, n).ravel() for m in motions])


def make_set(seed: int, per_class: int, subjects: range, classes=CLASSES, fps: float = 30.0) -> list[Motion]:
    """``per_class`` demonstrations of each class; generator ``[seed, class index]``, subjects drawn from
    ``subjects`` by the same generator."""
    out = []
    for c, label in enumerate(classes):
        rng = np.random.default_rng([seed, c])
        for _ in range(per_class):
            subject = int(rng.integers(subjects.start, subjects.stop))
            out.extend(demonstrations(label, 1, rng, fps=fps, subject=subject))
    return out


def nearest_class(train: list[Motion], test: list[Motion], classes=CLASSES) -> tuple[np.ndarray, float]:
    """Confusion matrix ``(C, C)`` (rows: true class, columns: predicted; counts) and accuracy."""
    xtr, xte = features(train), features(test)
    ytr = np.array([classes.index(m.label) for m in train])
    yte = np.array([classes.index(m.label) for m in test])
    means = np.stack([xtr[ytr == c].mean(axis=0) for c in range(len(classes))])
    dist = np.linalg.norm(xte[:, None, :] - means[None, :, :], axis=2)
    pred = dist.argmin(axis=1)
    confusion = np.zeros((len(classes), len(classes)), dtype=int)
    np.add.at(confusion, (yte, pred), 1)
    return confusion, float(np.mean(pred == yte))


def format_confusion(confusion: np.ndarray, classes=CLASSES) -> str:
    """A Markdown table of the confusion matrix (rows true, columns predicted)."""
    short = [c[:5] for c in classes]
    lines = ["| true \\ pred | " + " | ".join(short) + " |", "|---" * (len(classes) + 1) + "|"]
    for c, row in zip(classes, confusion):
        lines.append(f"| {c} | " + " | ".join(str(v) if v else "." for v in row) + " |")
    return "\n".join(lines)
