"""The both-handed database: the feature mirror against mirrored performances, the database closed under the
mirror, its chains, its files, recognition along the twin of a path, and the scenario's ``test.left``."""

import numpy as np
import pytest
from scipy.special import logsumexp

from engine_fixtures import CLASSES, synthetic_demos, synthetic_observation
from harness.engine import MotionDatabase, TrackerConfig, motion_features, recognize_features
from harness.engine.features import mirror_features
from harness.engine.model import EngineModel
from harness.engine.scoring import Scorer, path_recognition
from harness.engine.track import twin
from harness.errors import EngineError
from harness.evaluation import pipeline, runner
from harness.evaluation.loading import parse_scenario
from harness.evaluation.scenario import ScenarioError
from harness.motion.performer import CYCLIC, perform, training_set

K = 6


@pytest.fixture(scope="module")
def demos(body):
    rng = np.random.default_rng(1)
    return [m for c in CLASSES for m in synthetic_demos(body, c, 4, rng)]


@pytest.fixture(scope="module")
def both(demos):
    return MotionDatabase(n_states=K, cyclic=("march", "wave"), n_iter=5).fit(demos)


def _log_likelihood(db: MotionDatabase, features: np.ndarray) -> np.ndarray:
    """``(C,)`` ``log p(y_1:T | c)`` by the plain forward recursion in log space (no pruning, no spread)."""
    log_b = db.log_emissions(features)                                   # (T, C, S)
    with np.errstate(divide="ignore"):
        log_a, log_pi = np.log(db.transmat_), np.log(db.startprob_)
    alpha = log_pi + log_b[0]
    for t in range(1, len(log_b)):
        alpha = logsumexp(alpha[:, :, None] + log_a, axis=1) + log_b[t]
    return logsumexp(alpha, axis=1)


@pytest.mark.parametrize("label", ["wave", "throw", "walk", "kick"])
def test_the_mirrored_features_are_the_features_of_the_left_sided_performance(body, label):
    """The performer's left-sided take (the plan mirrored, then clipped, oriented and grounded by FK on its
    own) has exactly the mirrored features of its right-sided twin drawn from the same generator."""
    right = perform(label, np.random.default_rng(5), subject=3, body=body, left=0.0)[0]
    left = perform(label, np.random.default_rng(5), subject=3, body=body, left=1.0)[0]
    f_right, f_left = motion_features(right), motion_features(left)
    assert np.abs(f_left - f_right).max() > 1.0                         # the sides differ
    np.testing.assert_allclose(f_left, mirror_features(f_right), atol=1e-12)


def test_the_database_is_closed_under_the_mirror(both, body):
    """``p(M y | c) = p(y | c)`` for every primitive, by an independent forward recursion and by the engine's
    recognition (the recursion runs on a permutation of the same numbers)."""
    for label in CLASSES:
        f = motion_features(synthetic_demos(body, label, 1, np.random.default_rng(7))[0])
        np.testing.assert_allclose(_log_likelihood(both, mirror_features(f)), _log_likelihood(both, f),
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(recognize_features(both, mirror_features(f)), recognize_features(both, f),
                                   atol=1e-9)


def test_a_one_sided_database_is_not_closed_under_the_mirror(demos, body):
    """The counterpart of the test above: without the mirror chains the mirrored wave is much less likely."""
    one = MotionDatabase(n_states=K, cyclic=("march", "wave"), n_iter=5, mirrored=False).fit(demos)
    f = motion_features(synthetic_demos(body, "wave", 1, np.random.default_rng(7))[0])
    wave = list(one.classes_).index("wave")
    assert _log_likelihood(one, f)[wave] - _log_likelihood(one, mirror_features(f))[wave] > 100.0


def test_the_chains_are_the_fitted_hmm_and_its_mirror_image(both, demos):
    one = MotionDatabase(n_states=K, cyclic=("march", "wave"), n_iter=5, mirrored=False).fit(demos)
    C = len(CLASSES)
    assert both.means_.shape == (C, 2 * K, 106) and both.transmat_.shape == (C, 2 * K, 2 * K)
    np.testing.assert_allclose(both.transmat_.sum(axis=2), 1.0, atol=1e-12)
    np.testing.assert_allclose(both.startprob_.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(both.transmat_[:, :K, K:] == 0) and np.all(both.transmat_[:, K:, :K] == 0)
    np.testing.assert_array_equal(both.transmat_[:, K:, K:], both.transmat_[:, :K, :K])
    np.testing.assert_array_equal(both.startprob_[:, K:], both.startprob_[:, :K])
    np.testing.assert_array_equal(both.means_[:, K:], mirror_features(both.means_[:, :K]))
    np.testing.assert_array_equal(both.covars_[:, K:], np.abs(mirror_features(both.covars_[:, :K])))
    # A cyclic primitive wraps within each chain, from its last state to its first.
    march = list(both.classes_).index("march")
    assert both.transmat_[march, K - 1, 0] > 0 and both.transmat_[march, 2 * K - 1, K] > 0
    np.testing.assert_array_equal(both.last_states(), [K - 1, 2 * K - 1])
    # Chain A is the one-sided database, bit for bit (the same fit; the mirror is added after it).
    np.testing.assert_array_equal(both.means_[:, :K], one.means_)
    np.testing.assert_array_equal(both.covars_[:, :K], one.covars_)
    np.testing.assert_array_equal(both.transmat_[:, :K, :K], one.transmat_)
    np.testing.assert_array_equal(2 * both.startprob_[:, :K], one.startprob_)


@pytest.mark.parametrize("mirrored", [True, False])
def test_the_database_file_keeps_its_sides(demos, tmp_path, mirrored):
    db = MotionDatabase(n_states=K, cyclic=("march", "wave"), n_iter=2, mirrored=mirrored).fit(demos)
    db.save(tmp_path / "db.npz")
    back = MotionDatabase.load(tmp_path / "db.npz")
    assert back.mirrored == mirrored and back.n_states == K
    for name in ("means_", "covars_", "transmat_", "startprob_"):
        np.testing.assert_array_equal(getattr(back, name), getattr(db, name))
    back.mirrored = not mirrored                  # the arrays no longer fit the declared chains
    with pytest.raises(EngineError, match="chains of"):
        back.validate()


@pytest.fixture(scope="module")
def performed_classes(body):
    return training_set(("wave", "punch", "throw", "squat", "bow"), 3, seed=0, body=body)


# The primitives whose mirror image a one-sided database cannot explain. Since the calibration of issue 24 (the
# punch fitted on the joints its captures measure) the punch's guard and trunk twist make its mirror image close
# enough for a one-sided punch model (measured: 1.00 along the twin, with the group floor or the human floor).
STRONGLY_ONE_SIDED = ("wave", "throw")


@pytest.mark.parametrize("mirrored", [True, False])
def test_recognition_along_the_twin_of_a_path_is_recognition_along_the_path(body, performed_classes, mirrored):
    """The engine's recognition at given poses (``path_recognition``) along a scripted one-sided take's true
    base path and along its exact twin (``track.twin``: depth-reflected, the body mirrored). Along the twin the
    flows are explained by the mirrored body, which only a both-handed database models.

    The two posteriors are not equal, only their decision: the twin is the image of the mirrored body only
    under orthographic projection of unlabeled points (track.py's docstring), while the engine models
    perspective, its own model points (a surface sample, not mirror-symmetric) and self-occlusion, which
    the depth reflection turns front to back. So with the mirrored database both paths must give the true
    class; with the one-sided one the twin of a strongly one-sided primitive must lose it (else this test could
    not fail). Scored with the flows' likelihood, as the engine scores a given pose (with the velocities given
    the positions this small database reads the wave along its own true path as a punch or a throw).

    One take of this small database (three demonstrations a class) is decided differently under different draws
    of the model points (measured: 150 points drawn at random with seed 7 read all three takes right along the
    path, with seed 8 none), so each decision is the majority of three draws of 150 evenly spread points."""
    cfg = TrackerConfig.from_dict({"likelihood.recognise_velocities": False})
    db = MotionDatabase(n_states=8, cyclic=CYCLIC, n_iter=5, mirrored=mirrored).fit(performed_classes)
    models = [EngineModel.build(db, body, 150, seed) for seed in (7, 8, 9)]
    for label in ("wave", "punch", "throw"):
        rng = np.random.default_rng(100)
        motion = perform(label, rng, subject=1000, body=body)[0]
        obs, pos, quat = synthetic_observation(body, motion, rng, heading=np.pi)
        true_class = list(db.classes_).index(label)
        along_path = [path_recognition(Scorer(m, cfg.likelihood), cfg.belief, obs, pos, quat)[1][-1] for m in models]
        along_twin = [path_recognition(Scorer(m, cfg.likelihood), cfg.belief, obs, pos, twin(quat))[1][-1]
                      for m in models]
        assert sum(p.argmax() == true_class for p in along_path) >= 2, (label, along_path)
        if mirrored:
            assert sum(p.argmax() == true_class for p in along_twin) >= 2, (label, along_twin)
        elif label in STRONGLY_ONE_SIDED:
            assert sum(p[true_class] < 0.5 for p in along_twin) >= 2, (label, along_twin)

TINY = {"name": "sides", "seed": 3, "database": {"classes": ["punch", "squat"], "train_demos": 2, "states": 4},
        "test": {"demos_per_class": 3}}


@pytest.mark.parametrize("left", [-0.1, 1.5, "half"])
def test_test_left_outside_zero_to_one_is_refused(left):
    with pytest.raises(ScenarioError, match=r"test\.left"):
        parse_scenario({**TINY, "test": {"left": left}})


def test_test_left_is_for_procedural_test_performances_only():
    with pytest.raises(ScenarioError, match=r"test\.left: only procedural test performances"):
        parse_scenario({**TINY, "test": {"left": 0.5, "motions": "captures"}})


def test_test_left_one_makes_every_test_performance_left_sided(tmp_path):
    """Punch is calibrated right-sided (left share 0): by default no test performer mirrors it; with
    ``test.left: 1.0`` every one does, whatever its laterality, and performs the mirror image of the same take."""
    default = runner.plan(parse_scenario(TINY), tmp_path)
    left = runner.plan(parse_scenario({**TINY, "test": {**TINY["test"], "left": 1.0}}), tmp_path)
    punches = [(a, b) for a, b in zip(default, left) if a.test_class == "punch"]
    assert len(punches) == 3
    for a, b in punches:
        right_take, left_take = pipeline.test_motion(a), pipeline.test_motion(b)
        np.testing.assert_allclose(motion_features(left_take), mirror_features(motion_features(right_take)),
                                   atol=1e-12)
    assert parse_scenario(TINY).database.mirrored
    # The database's demonstrations keep their sides: the same training set and key either way.
    assert pipeline.database_key(parse_scenario(TINY), pipeline.training_motions(parse_scenario(TINY), None)) == \
        pipeline.database_key(parse_scenario({**TINY, "test": {"left": 1.0}}),
                              pipeline.training_motions(parse_scenario({**TINY, "test": {"left": 1.0}}), None))
    one_sided = parse_scenario({**TINY, "database": {**TINY["database"], "mirrored": False}})
    assert pipeline.database_key(one_sided, []) != pipeline.database_key(parse_scenario(TINY), [])
