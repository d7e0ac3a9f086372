"""``benchmarks/twin_posture.py``'s reading of the motion from the flows (``--read-motion``), a diagnosis the
engine's docs rest on: its linear map against the engine's own projection, and its posterior's limits."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from harness import geometry  # noqa: E402
from harness.engine.features import ANGLE_RATES, ANGLES  # noqa: E402
from harness.engine.model import EngineModel  # noqa: E402
from harness.engine.transform import JointGaussians, state_point_distributions, to_image  # noqa: E402
from harness.pinhole import Intrinsics  # noqa: E402
from twin_posture import image_velocity_map, read_motion  # noqa: E402

INTR = Intrinsics(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)


def _scene(body, trained, rng):
    model = EngineModel.build(trained, body, 40, 3)
    features = model.db_means[3].copy()
    features[ANGLE_RATES.start:] = rng.normal(0.0, 0.5, 56)
    rot = geometry.to_matrix(geometry.normalize(np.array([0.9, 0.1, 0.3, 0.05])))
    position = np.array([0.1, 0.2, 4.0])
    dists = state_point_distributions(model.body, JointGaussians.from_features(features[None], np.zeros((1, 106))),
                                      model.points, model.spread)
    return model, features, rot, position, to_image(INTR, rot[None], position[None], dists)


def test_the_image_velocity_map_is_the_engines_projection(body, trained):
    """``Pi R (J theta_dot + v + omega x x)`` at every model point equals the image velocity the engine's transform
    and projection give the same features (chain rule through MuJoCo-checked kinematics: an independent path)."""
    model, features, rot, position, img = _scene(body, trained, np.random.default_rng(0))
    a = image_velocity_map(model, INTR, features[ANGLES], rot, position, np.ones(len(img.flow[0]), dtype=bool))
    got = a @ features[ANGLE_RATES.start:]
    np.testing.assert_allclose(got, img.flow[0], rtol=1e-9, atol=1e-9 * np.abs(img.flow[0]).max())


def test_reading_the_motion_keeps_the_prior_where_the_flows_say_nothing(body, trained):
    """With flows known to an enormous velocity noise the posterior is the prior (the motion's mean and variance);
    the angles are never touched."""
    model, features, rot, position, img = _scene(body, trained, np.random.default_rng(1))
    visible = img.visibility[0] > 0
    frame = SimpleNamespace(flows=np.concatenate([img.pix[0][visible], img.flow[0][visible]], axis=1), intr=INTR)
    mean, var = features.copy(), np.full(106, 0.04)
    mean[ANGLE_RATES.start:] = 0.0
    got, got_var = read_motion(model, frame, rot, position, mean, var, img, vel_std=1e9, noise_px=1.0)
    np.testing.assert_allclose(got, mean, atol=1e-9)
    np.testing.assert_allclose(got_var, var, rtol=1e-9)


def test_reading_the_motion_fits_the_flows_it_is_given(body, trained):
    """From a prior mean of zero motion, exact flows at the visible points pull the read motion's predicted image
    velocities most of the way to the flows (the soft assignment by position blurs neighbouring points, so not
    all the way); the prior's own prediction, zero, is as far as the flows themselves."""
    model, features, rot, position, img = _scene(body, trained, np.random.default_rng(2))
    visible = img.visibility[0] > 0
    flows = np.concatenate([img.pix[0][visible], img.flow[0][visible]], axis=1)
    mean = features.copy()
    mean[ANGLE_RATES.start:] = 0.0
    got, _ = read_motion(model, SimpleNamespace(flows=flows, intr=INTR), rot, position, mean, np.full(106, 1.0), img,
                         vel_std=5.0, noise_px=1.0)
    a = image_velocity_map(model, INTR, mean[ANGLES], rot, position, visible)
    residual = np.linalg.norm(a @ got[ANGLE_RATES.start:] - flows[:, 2:])
    assert residual < 0.5 * np.linalg.norm(flows[:, 2:])
