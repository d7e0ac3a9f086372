"""Recognition over a stream: the joined forward recursion against brute-force enumeration of state paths."""

import itertools

import numpy as np
import pytest

from harness.engine.database import MotionDatabase
from harness.engine.features import N_FEATURES
from harness.engine.recognition import Recognizer
from harness.engine.switching import SwitchingRecognizer, exit_states
from harness.errors import EngineError

SWITCH = 0.2
SPREAD = 0.1


def two_primitives(K: int = 3, seed: int = 0) -> MotionDatabase:
    """A synthetic database: a cyclic primitive (``walk``, its last state wraps to the first) and a non-cyclic one
    (``squat``, its last state absorbing), left-to-right with random stay probabilities and start
    distributions."""
    rng = np.random.default_rng(seed)
    db = MotionDatabase(n_states=K, cyclic=("walk",), mirrored=False)
    db.classes_ = np.array(["squat", "walk"])
    db.cyclic_ = np.array([False, True])
    trans = np.zeros((2, K, K))
    for c in range(2):
        stay = rng.uniform(0.3, 0.9, K)
        for j in range(K):
            trans[c, j, j] = stay[j]
            trans[c, j, (j + 1) % K] += 1.0 - stay[j]
    trans[0, -1] = 0.0
    trans[0, -1, -1] = 1.0                           # squat: the end rest is absorbing
    db.transmat_ = trans
    db.startprob_ = rng.dirichlet(np.ones(K), size=2)
    db.means_ = np.zeros((2, K, N_FEATURES))
    db.covars_ = np.ones((2, K, N_FEATURES))
    db.fps_ = 30.0
    return db


def step_probability(db: MotionDatabase, c: int, j: int, c2: int, k: int) -> float:
    """``p(c2, k | c, j)`` written from the model's definition: exit with probability SWITCH from an exit state
    (the squat's last state, any walk state), then any primitive uniformly, entered at its spread start
    distribution; else the primitive's own transition."""
    K = db.startprob_.shape[1]
    name = db.classes_[c]
    exits = SWITCH if (name == "walk" or j == K - 1) else 0.0
    entry = (1 - SPREAD) * db.startprob_[c2, k] + SPREAD / K
    p = exits * (1.0 / 2) * entry
    if c2 == c:
        p += (1 - exits) * db.transmat_[c, j, k]
    return p


def brute_force(db: MotionDatabase, log_b: np.ndarray) -> tuple[list[np.ndarray], float]:
    """Filtered posteriors ``p(z_t | y_0..t)`` per frame and ``log p(y_0..T-1)``, by summing over every path."""
    T, C, K = log_b.shape
    states = [(c, k) for c in range(C) for k in range(K)]
    b = np.exp(log_b)
    posteriors, total = [], 0.0
    for t in range(T):
        post = np.zeros((C, K))
        for path in itertools.product(states, repeat=t + 1):
            c0, k0 = path[0]
            p = (1 - SPREAD) * db.startprob_[c0, k0] / C + SPREAD / (C * K)
            p *= b[0, c0, k0]
            for s in range(1, t + 1):
                p *= step_probability(db, *path[s - 1], *path[s]) * b[s, path[s][0], path[s][1]]
            post[path[-1]] += p
        total = post.sum()
        posteriors.append(post / total)
    return posteriors, float(np.log(total))


def test_forward_recursion_equals_brute_force_enumeration():
    db = two_primitives()
    rng = np.random.default_rng(1)
    log_b = rng.normal(0.0, 2.0, size=(5, 2, 3))
    rec = SwitchingRecognizer(db, SWITCH, start_spread=SPREAD, prune=0.0)
    posteriors, log_evidence = brute_force(db, log_b)
    total = 0.0
    for t in range(len(log_b)):
        rec.predict()
        total += rec.update(log_b[t])
        np.testing.assert_allclose(rec.posterior, posteriors[t], atol=1e-9)
        np.testing.assert_allclose(rec.class_posterior, posteriors[t].sum(axis=1), atol=1e-9)
    assert total == pytest.approx(log_evidence, abs=1e-9)


def test_the_joined_transition_matrix_is_the_definition():
    db = two_primitives(K=4, seed=2)
    rec = SwitchingRecognizer(db, SWITCH, start_spread=SPREAD, prune=0.0)
    mat = rec.transition_matrix()
    K = 4
    expect = np.array([[step_probability(db, c, j, c2, k) for c2 in range(2) for k in range(K)]
                       for c in range(2) for j in range(K)])
    np.testing.assert_allclose(mat, expect, atol=1e-12)
    np.testing.assert_allclose(mat.sum(axis=1), 1.0, atol=1e-12)
    assert exit_states(db).tolist() == [[False, False, False, True], [True] * 4]


def test_without_switching_it_is_the_isolated_recursion():
    db = two_primitives(K=4, seed=3)
    log_b = np.random.default_rng(4).normal(0.0, 3.0, size=(12, 2, 4))
    a, b = SwitchingRecognizer(db, 0.0, start_spread=SPREAD, prune=1e-3), Recognizer(db, SPREAD, prune=1e-3)
    for t in range(len(log_b)):
        a.predict()
        b.predict()
        assert a.update(log_b[t]) == pytest.approx(b.update(log_b[t]), abs=1e-12)
        np.testing.assert_allclose(a.log_alpha, b.log_alpha, atol=1e-12)
        assert np.array_equal(a.active(), b.active())


def test_a_primitive_change_is_followed_only_when_switching_is_allowed():
    """Frames that fit the squat, then frames that fit only the walk: the joined recursion moves to the walk at
    once; the isolated one cannot leave the squat's absorbing end and keeps the squat's evidence from before."""
    db = two_primitives()
    log_b = np.full((40, 2, 3), -10.0)
    log_b[:20, 0, :] = 0.0                  # squat fits (every state), walk does not
    log_b[:20, 1, :] = -1.0
    log_b[20:, 1, :] = 0.0                  # then the walk fits, the squat less (3 nats a frame)
    log_b[20:, 0, :] = -3.0
    joined, isolated = SwitchingRecognizer(db, 0.02, SPREAD, prune=0.0), Recognizer(db, SPREAD, prune=0.0)
    for t in range(40):
        for rec in (joined, isolated):
            rec.predict()
            rec.update(log_b[t])
        if t == 19:
            assert joined.class_posterior[0] > 0.99 and isolated.class_posterior[0] > 0.99
        if t == 23:
            assert joined.class_posterior[1] > 0.99
            assert isolated.class_posterior[0] > 0.99       # 20 nats behind, 12 made up
    # The isolated recursion only gets there once the walk's evidence outweighs 20 frames of the squat's.
    assert isolated.class_posterior[1] > 0.99


def test_settings_are_checked():
    with pytest.raises(EngineError, match=r"switch probability must be in \[0, 1\)"):
        SwitchingRecognizer(two_primitives(), 1.0)


def test_a_track_gets_a_switching_recognizer_when_asked():
    from harness.engine.config import TrackerConfig
    from harness.engine.track import new_recognizer

    db = two_primitives()
    switching = TrackerConfig.from_dict({"belief.primitive_switch": 0.01}).belief
    assert isinstance(new_recognizer(db, switching), SwitchingRecognizer)
    assert type(new_recognizer(db, TrackerConfig().belief)) is Recognizer
    with pytest.raises(EngineError, match="primitive_switch"):
        TrackerConfig.from_dict({"belief.primitive_switch": 1.5})


def test_online_labels_report_a_change_after_min_frames_of_lead():
    from harness.engine.switching import online_labels

    best = [0, 0, 1, 0, 1, 1, 1, 2, 2, 0, 0, 0]
    post = np.eye(3)[best] * 0.8 + 0.1
    assert online_labels(post, 1).tolist() == best
    # A lead of one frame (1 at frame 2) or two (2 at frames 7-8) is not reported; three frames are.
    assert online_labels(post, 3).tolist() == [0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 0]
    with pytest.raises(EngineError, match="min_frames"):
        online_labels(post, 0)


def test_a_stream_track_prunes_by_stream_prune_so_a_primitive_entered_mid_stream_keeps_its_spread_states():
    """``new_recognizer`` gives a stream's track the switching recursion with ``stream_prune``, a clip's track the
    isolated one with ``prune``. With a start distribution of 0.95 on one state and the spread's 0.05 over 40
    states (1.25e-3 each, relative to the best), 1e-2 drops the spread states while 1e-4 keeps them all: the entry
    of a primitive mid-stream must be followable."""
    from dataclasses import replace

    from harness.engine.config import BeliefSettings
    from harness.engine.track import new_recognizer

    K = 40
    db = two_primitives(K)
    db.startprob_ = np.full((2, K), 0.0)
    db.startprob_[:, 0] = 1.0
    belief = BeliefSettings(start_spread=0.05, prune=1e-2, stream_prune=1e-4)
    stream = new_recognizer(db, replace(belief, primitive_switch=0.02))
    clip = new_recognizer(db, belief)
    assert isinstance(stream, SwitchingRecognizer) and not isinstance(clip, SwitchingRecognizer)
    assert stream.active().all()
    assert clip.active().sum() == 2 and clip.active()[:, 0].all()
