"""Stream metrics against hand computations and against the reference implementation's algorithm."""

from functools import lru_cache

import numpy as np
import pytest

from harness.evaluation.metrics import MetricError
from harness.evaluation.stream_metrics import (boundary_delays, edit_score, f1_counts, f1_score, frame_accuracy,
                                               levenshtein, stream_scores)

T = "transition"


def labels(text: str) -> np.ndarray:
    """``"AAATTBB"`` -> per-frame labels, ``T`` meaning transition."""
    return np.array([T if c == "T" else c for c in text])


def test_frame_accuracy_leaves_transitions_out():
    true, rec = labels("AAATTBBBBCC"), labels("AAAABBBBCCC")
    # Non-transition frames: A x3 (all right), B x4 (3 right), C x2 (both right): 8 of 9.
    assert frame_accuracy(rec, true) == pytest.approx(8 / 9)
    assert np.isnan(frame_accuracy(labels("AA"), labels("TT")))


def test_edit_score_by_hand():
    # Y = A B C; P = A B A C: one insertion, max length 4.
    assert edit_score(labels("AAABBBAACC"), labels("AAATBBBTCC")) == pytest.approx(1 - 1 / 4)
    assert edit_score(labels("AAAABBBBCCC"), labels("AAATTBBBBCC")) == 1.0
    # Y = A B; P = C: one substitution and one deletion, max length 2.
    assert edit_score(labels("CCCCC"), labels("AATBB")) == 0.0


def test_f1_by_hand():
    true = labels("AAAAATTBBBBBCCCC")      # A [0,5), B [7,12), C [12,16)
    rec = labels("AAAAAAAAAABBCCCC")       # A [0,10), B [10,12), C [12,16)
    # A: IoU 5/10 = 0.5; B: IoU 2/5 = 0.4; C: IoU 1.
    assert f1_counts(rec, true, 0.10) == (3, 0, 0)
    assert f1_counts(rec, true, 0.50) == (2, 1, 1)
    assert f1_score(rec, true, 0.50) == pytest.approx(2 * 2 / (2 * 2 + 1 + 1))
    assert f1_counts(rec, true, 0.60) == (1, 2, 2)
    # A second recognised segment of a label cannot match the same true segment again.
    assert f1_counts(labels("AABAA"), labels("AAAAA"), 0.1) == (1, 2, 0)


def test_boundary_delay_by_hand():
    true = labels("AAATTBBBBCC")
    # B first recognised at frame 6 (its segment starts at 5): 1 frame; C at 10 (starts at 9): 1 frame.
    assert boundary_delays(labels("AAAAAABBBBC"), true).tolist() == [1.0, 1.0]
    # Recognised during the transition: no delay. C never recognised: its segment's length (2 frames).
    assert boundary_delays(labels("AAAABBBBBBB"), true).tolist() == [0.0, 2.0]
    scores = stream_scores(labels("AAAAAABBBBC"), true, fps=10.0)
    assert scores["boundary_delay_s"] == pytest.approx(0.1)
    assert set(scores) == {"frame_accuracy", "edit_score", "f1_10", "f1_25", "f1_50", "boundary_delay_s"}
    assert np.isnan(stream_scores(labels("AAA"), labels("AAA"), 30.0)["boundary_delay_s"])


def test_bad_input_is_named():
    with pytest.raises(MetricError, match="equally long"):
        frame_accuracy(labels("AA"), labels("AAA"))


@lru_cache(maxsize=None)
def _edit_by_recursion(a: tuple, b: tuple) -> int:
    if not a or not b:
        return len(a) + len(b)
    return min(_edit_by_recursion(a[1:], b) + 1, _edit_by_recursion(a, b[1:]) + 1,
               _edit_by_recursion(a[1:], b[1:]) + (a[0] != b[0]))


def _reference_segments(frame_wise_labels, bg_class=(T,)):
    """MS-TCN's ``get_labels_start_end_time`` (eval.py), with the last segment's end exclusive like the others."""
    labels_, starts, ends = [], [], []
    last_label = frame_wise_labels[0]
    if frame_wise_labels[0] not in bg_class:
        labels_.append(frame_wise_labels[0])
        starts.append(0)
    for i in range(len(frame_wise_labels)):
        if frame_wise_labels[i] != last_label:
            if frame_wise_labels[i] not in bg_class:
                labels_.append(frame_wise_labels[i])
                starts.append(i)
            if last_label not in bg_class:
                ends.append(i)
            last_label = frame_wise_labels[i]
    if last_label not in bg_class:
        ends.append(len(frame_wise_labels))
    return labels_, starts, ends


def _reference_f_score(recognized, ground_truth, overlap):
    """MS-TCN's ``f_score`` (eval.py)."""
    p_label, p_start, p_end = _reference_segments(recognized)
    y_label, y_start, y_end = _reference_segments(ground_truth)
    tp, fp = 0, 0
    hits = np.zeros(len(y_label))
    for j in range(len(p_label)):
        intersection = np.minimum(p_end[j], y_end) - np.maximum(p_start[j], y_start)
        union = np.maximum(p_end[j], y_end) - np.minimum(p_start[j], y_start)
        iou = (1.0 * intersection / union) * np.array([p_label[j] == y_label[x] for x in range(len(y_label))])
        idx = np.array(iou).argmax()
        if iou[idx] >= overlap and not hits[idx]:
            tp += 1
            hits[idx] = 1
        else:
            fp += 1
    return tp, fp, len(y_label) - int(hits.sum())


def test_against_the_reference_algorithm_on_random_labellings():
    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(5, 40))
        # Piecewise-constant labellings: runs of random length, transitions included in the truth.
        def draw(alphabet):
            out = []
            while len(out) < n:
                out += [str(rng.choice(alphabet))] * int(rng.integers(1, 8))
            return np.array(out[:n])
        true, rec = draw(["A", "B", "C", T]), draw(["A", "B", "C"])
        if not (true != T).any():
            continue
        for k in (0.1, 0.25, 0.5):
            assert f1_counts(rec, true, k) == _reference_f_score(list(rec), list(true), k)
        p = [s for s in _reference_segments(list(rec))[0]]
        y = [s for s in _reference_segments(list(true))[0]]
        assert levenshtein(p, y) == _edit_by_recursion(tuple(p), tuple(y))
