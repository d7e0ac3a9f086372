import mujoco
import numpy as np
import pytest

from harness import geometry
from harness.motion import Motion, MotionError
from harness.observation import Observation, ObservationError
from harness.pinhole import Intrinsics


def _smooth_motion(body, rng, n=120, fps=60.0):
    t = np.arange(n) / fps
    freq = rng.uniform(0.3, 1.0, size=50)
    phase = rng.uniform(0, 2 * np.pi, size=50)
    angles = 0.3 * np.sin(2 * np.pi * freq * t[:, None] + phase)
    pos = np.stack([0.8 * t, 0.1 * np.sin(t), 0.95 + 0.02 * np.cos(3 * t)], axis=1)
    rv = np.stack([0.1 * np.sin(2 * t), 0.2 * np.cos(t), 0.9 * t], axis=1)
    quat = geometry.exp(rv)
    return Motion(body.qpos(angles, pos, quat), fps, "test", subject="s1", demo="d1")


def test_velocities_match_mujoco_differentiate_pos(body, rng):
    m = _smooth_motion(body, rng)
    vel = m.velocities
    dt = 1.0 / m.fps
    qvel = np.empty(56)
    for t in range(1, m.n_frames - 1):
        mujoco.mj_differentiatePos(body.model, qvel, 2 * dt, m.qpos[t - 1], m.qpos[t + 1])
        np.testing.assert_allclose(vel.qvel()[t], qvel, atol=1e-10)


def test_velocities_match_analytic_rates(body, rng):
    """Central differences of a sinusoid against its derivative (second-order error)."""
    m = _smooth_motion(body, rng, n=600, fps=240.0)
    t = m.times
    np.testing.assert_allclose(m.velocities.base_linear_world[1:-1, 0], 0.8, atol=1e-9)
    np.testing.assert_allclose(m.velocities.base_linear_world[1:-1, 1], 0.1 * np.cos(t[1:-1]), atol=1e-5)
    lin_base = geometry.rotate(geometry.conjugate(m.base_quat), m.velocities.base_linear_world)
    np.testing.assert_allclose(m.velocities.base_linear, lin_base, atol=1e-12)


def test_resample_keeps_the_trajectory(body, rng):
    m = _smooth_motion(body, rng, n=241, fps=120.0)
    half = m.resample(60.0)
    assert half.n_frames == 121 and half.fps == 60.0
    np.testing.assert_allclose(half.qpos, m.qpos[::2], atol=1e-12)
    up = m.resample(240.0)
    np.testing.assert_allclose(up.qpos[::2], m.qpos, atol=1e-12)
    assert np.allclose(np.linalg.norm(up.base_quat, axis=1), 1.0)


def test_save_load_is_exact(tmp_path, body, rng):
    m = _smooth_motion(body, rng).replace(style="tired", source="studio")
    m.save(tmp_path / "m.npz")
    back = Motion.load(tmp_path / "m.npz")
    assert np.array_equal(back.qpos, m.qpos)
    assert (back.fps, back.label, back.subject, back.demo, back.source, back.style) == (
        m.fps, m.label, m.subject, m.demo, m.source, m.style)
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        assert set(z.files) == {"qpos", "fps", "label", "subject", "demo", "source", "style"}


def test_a_single_precision_motion_loads_within_its_rounding(tmp_path, body, rng):
    """The capture library keeps float32, compressed: loaded, every value within float32's rounding of the
    original and every base quaternion of unit length again (``Motion`` refuses one that is not)."""
    m = _smooth_motion(body, rng)
    m.save(tmp_path / "m.npz", dtype=np.float32, compressed=True)
    back = Motion.load(tmp_path / "m.npz")
    assert back.qpos.dtype == np.float64
    np.testing.assert_allclose(back.qpos, m.qpos, rtol=2e-7, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(back.qpos[:, 3:7], axis=1), 1.0, atol=1e-12)


def test_bad_motions(body):
    q = np.tile(body.zero_qpos(), (5, 1))
    with pytest.raises(MotionError, match=r"\(T, 57\)"):
        Motion(q[:, :50], 30.0, "x")
    bad = q.copy()
    bad[2, 10] = np.nan
    with pytest.raises(MotionError, match="NaN"):
        Motion(bad, 30.0, "x")
    with pytest.raises(MotionError, match="fps"):
        Motion(q, 0.0, "x")
    with pytest.raises(MotionError, match="outside"):
        Motion(q, 30.0, "x").slice(3, 9)


def test_observation_roundtrip_and_validation(tmp_path, rng):
    intr = Intrinsics.from_fov(45, 640, 480)
    flows = [np.empty((0, 4))] + [np.column_stack([rng.uniform(0, 640, k), rng.uniform(0, 480, k),
                                                   rng.normal(size=(k, 2))]) for k in (5, 0, 7)]
    obs = Observation(30.0, intr, flows).validate()
    obs.save(tmp_path / "o.npz")
    back = Observation.load(tmp_path / "o.npz")
    assert len(back) == 4 and back.intrinsics == intr
    for a, b in zip(flows, back.flows):
        assert np.array_equal(a, b)
    nan = [f.copy() for f in flows]
    nan[3][2, 1] = np.nan
    with pytest.raises(ObservationError, match="frame 3, row 2"):
        Observation(30.0, intr, nan).validate()
    out = [f.copy() for f in flows]
    out[1][0, 0] = -3.0
    with pytest.raises(ObservationError, match="frame 1, row 0.*outside"):
        Observation(30.0, intr, out).validate()
    with pytest.raises(ObservationError, match="no such observation file"):
        Observation.load(tmp_path / "missing.npz")
