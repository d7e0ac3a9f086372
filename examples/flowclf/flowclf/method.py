"""The method ``flow_knn``: the class posterior at every frame from the window of flows seen so far (causal), by the
k nearest training windows (``flowclf.train``). It recognises and does not recover the body.

Posterior of class ``c`` at frame ``t``: ``votes_c + ALPHA``, normalised over the database's ``C`` classes, where
``votes_c`` counts the ``K`` nearest training windows of class ``c`` (neighbours of a class the database lacks are
dropped; a class the model never saw gets ``ALPHA`` alone); before any frame has enough flows, every class alike.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from sklearn.neighbors import KNeighborsClassifier

from flowclf.features import window_descriptors
from harness.engine import Estimate
from harness.evaluation.methods import declare

MODEL = Path(__file__).with_name("model.npz")
K = 7          # neighbours
ALPHA = 0.5    # pseudo-votes per class: no probability is 0, so log_p_true stays finite


def _load(path: Path):
    if not path.is_file():
        raise FileNotFoundError(f"flowclf: no trained model at {path} (run python -m flowclf.train EXPORT)")
    with np.load(path, allow_pickle=False) as z:
        x, y, mean, std = z["x"], z["y"].astype(str), z["mean"], z["std"]
    return KNeighborsClassifier(n_neighbors=min(K, len(x))).fit(x, y), y, mean, std


_KNN, _LABELS, _MEAN, _STD = _load(MODEL)


@declare(recognises=True, recovers=False)
def estimate(inputs, engine):
    classes = list(inputs.classes)
    desc = window_descriptors(inputs.obs.flows)
    post = np.full((len(desc), len(classes)), 1.0 / len(classes))
    ok = np.all(np.isfinite(desc), axis=1)
    if ok.any():
        _, idx = _KNN.kneighbors((desc[ok] - _MEAN) / _STD)
        votes = np.zeros((len(idx), len(classes)))
        for c, name in enumerate(classes):
            votes[:, c] = (_LABELS[idx] == name).sum(axis=1)
        votes += ALPHA
        post[ok] = votes / votes.sum(axis=1, keepdims=True)
    return Estimate(np.asarray(classes), class_posterior=post)
