"""Scores of recognition over a stream: the action-segmentation standard. Labels in, numbers out.

True labels are per frame, a primitive or ``"transition"``; recognised labels are per frame (the engine's most
probable primitive). Transition frames are the background class of the segmentation literature: they are left
out of the frame accuracy, and transition segments are left out of the segment lists (as the ``bg_class`` of
the reference implementation, Farha and Gall, "MS-TCN", CVPR 2019, ``eval.py``). Segments are runs of equal
labels ``[start, stop)``.

- ``frame_accuracy``: the fraction of non-transition frames whose recognised label is the true one.
- ``edit_score``: ``1 - levenshtein(P, Y) / max(|P|, |Y|)`` over the ordered segment labels ``P`` (recognised)
  and ``Y`` (true): the segmental edit score of Lea, Flynn, Vidal, Reiter and Hager, "Temporal convolutional
  networks for action segmentation and detection", CVPR 2017 (there in percent; here a fraction).
- ``f1_10``, ``f1_25``, ``f1_50``: F1@k of the same paper: a recognised segment is a true positive if its
  intersection over union with the true segment of the same label it overlaps most is at least ``k`` and that
  true segment has not been matched yet; else a false positive; unmatched true segments are false negatives.
  Per run (the literature pools the counts over a data set; ``f1_counts`` gives them for pooling).
- ``boundary_delay_s``: the mean, over the true boundaries where a primitive begins after another one, of the
  time from the boundary (the first frame labelled with the new primitive) to the first frame recognised as it,
  searching from the start of the transition before it: a detection during the transition counts as no delay.
  A boundary not detected before its segment ends counts its segment's length (a lower bound of its delay).
"""

from __future__ import annotations

import numpy as np

from harness.evaluation.metrics import MetricError
from harness.motion.stream import TRANSITION, Segment, label_segments

STREAM_COLUMNS = ("frame_accuracy", "edit_score", "f1_10", "f1_25", "f1_50", "boundary_delay_s")
F1_OVERLAPS = {"f1_10": 0.10, "f1_25": 0.25, "f1_50": 0.50}


def _check(recognised, true) -> tuple[np.ndarray, np.ndarray]:
    r, t = np.asarray(recognised, dtype=str), np.asarray(true, dtype=str)
    if r.ndim != 1 or r.shape != t.shape or len(t) == 0:
        raise MetricError(f"recognised and true labels must be two equally long non-empty sequences, got "
                          f"{r.shape} and {t.shape}")
    return r, t


def action_segments(labels) -> list[Segment]:
    """The segments of a per-frame labelling, transition segments left out."""
    return [s for s in label_segments(labels) if s.label != TRANSITION]


def frame_accuracy(recognised, true) -> float:
    """Fraction of non-transition frames recognised right (NaN if every frame is a transition)."""
    r, t = _check(recognised, true)
    keep = t != TRANSITION
    return float(np.mean(r[keep] == t[keep])) if keep.any() else float("nan")


def levenshtein(a: list[str], b: list[str]) -> int:
    """Edit distance (insertions, deletions, substitutions, each 1) between two label sequences."""
    prev = np.arange(len(b) + 1)
    for i, x in enumerate(a, start=1):
        cur = np.empty_like(prev)
        cur[0] = i
        for j, y in enumerate(b, start=1):
            cur[j] = min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (x != y))
        prev = cur
    return int(prev[-1])


def edit_score(recognised, true) -> float:
    """Segmental edit score in [0, 1] (1: the same sequence of primitives); NaN if neither has a segment."""
    r, t = _check(recognised, true)
    p, y = [s.label for s in action_segments(r)], [s.label for s in action_segments(t)]
    if not p and not y:
        return float("nan")
    return 1.0 - levenshtein(p, y) / max(len(p), len(y))


def f1_counts(recognised, true, overlap: float) -> tuple[int, int, int]:
    """True positives, false positives and false negatives of the recognised segments at IoU ``overlap``."""
    r, t = _check(recognised, true)
    pred, gt = action_segments(r), action_segments(t)
    hit = np.zeros(len(gt), dtype=bool)
    tp = fp = 0
    starts = np.array([s.start for s in gt])
    stops = np.array([s.stop for s in gt])
    labels = np.array([s.label for s in gt])
    for seg in pred:
        inter = np.minimum(seg.stop, stops) - np.maximum(seg.start, starts)
        union = np.maximum(seg.stop, stops) - np.minimum(seg.start, starts)
        iou = np.where(labels == seg.label, inter / union, 0.0) if len(gt) else np.zeros(0)
        best = int(np.argmax(iou)) if len(gt) else -1
        if best >= 0 and iou[best] >= overlap and not hit[best]:
            tp += 1
            hit[best] = True
        else:
            fp += 1
    return tp, fp, int(len(gt) - hit.sum())


def f1_score(recognised, true, overlap: float) -> float:
    """F1@overlap of one labelling (0 when nothing matches; NaN if neither has a segment)."""
    tp, fp, fn = f1_counts(recognised, true, overlap)
    if tp + fp + fn == 0:
        return float("nan")
    return 2.0 * tp / (2.0 * tp + fp + fn)


def boundary_delays(recognised, true) -> np.ndarray:
    """Frames from each true boundary to its detection (see the module docstring), ``(B,)``."""
    r, t = _check(recognised, true)
    segs = label_segments(t)
    out = []
    previous_end = None                 # where the last primitive before this one ended
    for seg in segs:
        if seg.label == TRANSITION:
            continue
        if previous_end is not None:
            found = np.flatnonzero(r[previous_end:seg.stop] == seg.label)
            first = previous_end + found[0] if len(found) else seg.stop
            out.append(max(0, first - seg.start))
        previous_end = seg.stop
    return np.array(out, dtype=float)


def stream_scores(recognised, true, fps: float) -> dict:
    """The six stream columns of one run (``STREAM_COLUMNS``)."""
    delays = boundary_delays(recognised, true)
    return ({"frame_accuracy": frame_accuracy(recognised, true), "edit_score": edit_score(recognised, true)}
            | {name: f1_score(recognised, true, k) for name, k in F1_OVERLAPS.items()}
            | {"boundary_delay_s": float(delays.mean() / fps) if len(delays) else float("nan")})
