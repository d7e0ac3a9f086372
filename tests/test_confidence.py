"""The class posterior's calibration (issue 25): the calibrated posterior against its closed form, the fit
against labels drawn from a known calibration (Monte Carlo), and the frame records' log-space class posterior
against the probabilities it must equal where they do not underflow."""

import numpy as np
import pytest
from scipy.special import softmax

from harness.engine import TrackerConfig
from harness.engine.confidence import calibrated, fit, log_true
from harness.engine.records import FrameRecord, TrackRecord, causal_estimate
from harness.errors import EngineError


def test_the_calibrated_posterior_is_its_closed_form_and_keeps_the_order():
    rng = np.random.default_rng(0)
    log_post = rng.normal(0, 30, (50, 7))
    np.testing.assert_allclose(calibrated(log_post, 1.0, 0.0), softmax(log_post, axis=1), rtol=1e-12)
    p = calibrated(log_post, 7.5, 0.03)
    np.testing.assert_allclose(p, 0.97 * softmax(log_post / 7.5, axis=1) + 0.03 / 7, rtol=1e-12)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    assert np.all(p >= 0.03 / 7 - 1e-15)
    np.testing.assert_array_equal(np.argmax(p, axis=1), np.argmax(log_post, axis=1))
    with_missing = calibrated(np.array([0.0, -np.inf, -3.0]), 2.0, 0.0)      # a class no track holds
    assert with_missing[1] == 0.0 and with_missing.sum() == pytest.approx(1.0)
    for tau, eps in ((0.0, 0.1), (1.0, 1.0), (1.0, -0.1)):
        with pytest.raises(EngineError):
            calibrated(log_post, tau, eps)


def test_the_log_probability_of_the_true_class_is_the_log_of_the_calibrated_one_without_underflow():
    rng = np.random.default_rng(1)
    log_post = rng.normal(0, 10, (40, 5))
    true = rng.integers(0, 5, 40)
    np.testing.assert_allclose(log_true(log_post, true, 3.0, 0.02),
                               np.log(calibrated(log_post, 3.0, 0.02)[np.arange(40), true]), rtol=1e-10)
    far = np.array([[0.0, -5000.0]])                       # the true class 5000 nats down: e^-5000 underflows
    assert log_true(far, np.array([1]), 2.0, 0.0)[0] == pytest.approx(-2500.0)


def test_the_fit_recovers_the_calibration_the_labels_were_drawn_from():
    """Labels drawn from ``(1 - eps) softmax(l / tau) + eps / C`` for known (tau, eps): the fit finds them (within
    the Monte-Carlo spread of 6000 draws: about 5% in tau, 0.01 in eps)."""
    rng = np.random.default_rng(2)
    N, C = 6000, 10
    log_post = rng.normal(0, 150, (N, C))          # the engine's classes lie hundreds of nats apart
    for tau0, eps0 in ((8.0, 0.05), (25.0, 0.1)):
        p = calibrated(log_post, tau0, eps0)
        true = np.array([rng.choice(C, p=row) for row in p])
        tau, eps, bias = fit(log_post, true)
        assert tau == pytest.approx(tau0, rel=0.12)
        assert eps == pytest.approx(eps0, abs=0.025)
        assert bias == 0.0
    with pytest.raises(EngineError):
        fit(log_post[:1], true[:1])


def test_the_fit_recovers_the_background_class_bias_the_labels_were_drawn_from():
    """Labels drawn with a log prior of -40 nats on the last class (a background class): the fit finds the bias
    (within the Monte-Carlo spread of 6000 draws) as well as the temperature, and the bias moves the background's
    probability as its odds say."""
    rng = np.random.default_rng(3)
    N, C = 6000, 6
    log_post = rng.normal(0, 150, (N, C))
    bias0 = np.r_[np.zeros(C - 1), -40.0]
    p = calibrated(log_post, 20.0, 0.02, bias0)
    true = np.array([rng.choice(C, p=row) for row in p])
    tau, eps, bias = fit(log_post, true, unknown=C - 1)
    assert tau == pytest.approx(20.0, rel=0.12) and eps == pytest.approx(0.02, abs=0.025)
    assert bias == pytest.approx(-40.0, abs=8.0)
    even = np.zeros((1, 2))
    assert calibrated(even, 1.0, 0.0, np.array([0.0, np.log(3.0)]))[0, 1] == pytest.approx(0.75)


def _track(track_id, evidence, class_posterior):
    joint = np.outer(class_posterior, [0.5, 0.5])
    return TrackRecord(track_id, f"t{track_id}", evidence, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(57),
                       joint)


def test_the_records_class_posterior_in_log_space_is_the_mixture_and_sees_past_underflow():
    moderate = FrameRecord(0, (_track(0, -10.0, [0.7, 0.3, 0.0]), _track(1, -12.0, [0.1, 0.2, 0.7])), None, 0.0)
    joint, _ = moderate.decision()
    with np.errstate(divide="ignore"):
        np.testing.assert_allclose(moderate.log_class_posterior(), np.log(joint.sum(axis=1)), rtol=1e-12)
    # One track per primitive, 2000 nats apart: probabilities say 1 and 0, the log posterior says -2000.
    apart = FrameRecord(0, (_track(0, -100.0, [1.0, 0.0]), _track(1, -2100.0, [0.0, 1.0])), None, 0.0)
    np.testing.assert_allclose(apart.log_class_posterior(), [0.0, -2000.0], atol=1e-9)
    est = causal_estimate([apart, apart], np.array(["a", "b"]), {}, temperature=500.0, floor=0.1)
    np.testing.assert_allclose(est.raw_log_posterior[-1], [0.0, -2000.0], atol=1e-9)
    np.testing.assert_allclose(est.class_posterior[-1], 0.9 * softmax([0.0, -4.0]) + 0.05, rtol=1e-9)


def test_the_engine_settings_refuse_a_meaningless_calibration():
    for bad in ({"belief.posterior_temperature": 0.0}, {"belief.posterior_floor": 1.0},
                {"belief.posterior_floor": -0.01}):
        with pytest.raises(EngineError, match="posterior_"):
            TrackerConfig.from_dict(bad)
