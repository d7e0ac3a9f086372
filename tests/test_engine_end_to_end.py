"""A small end-to-end case: three simple primitives, facing-only camera, coarse initialisation."""

import numpy as np
import pytest

from engine_fixtures import CLASSES, synthetic_demos, synthetic_observation
from harness.engine import MotionDatabase, Tracker, TrackerConfig
from harness.errors import EngineError
from harness.observation import Observation, ObservationError


@pytest.fixture(scope="module")
def trained(body):
    rng = np.random.default_rng(1)
    train = [m for c in CLASSES for m in synthetic_demos(body, c, 5, rng)]
    return MotionDatabase(n_states=10, cyclic=("march", "wave")).fit(train)


def test_recognition_beats_chance_by_a_wide_margin(body, trained):
    rng = np.random.default_rng(99)
    tracker = Tracker(
        trained,
        body,
        TrackerConfig.from_dict({"tracks.particles": 150, "model.points": 120}),
        rng=np.random.default_rng(5),
    )
    right, pos_err = 0, []
    for c in CLASSES:
        for m in synthetic_demos(body, c, 2, rng):
            obs, base_pos, _ = synthetic_observation(body, m, rng)
            est = tracker.run(obs)
            assert est.qpos.shape == (len(obs), 57) and est.class_posterior.shape == (len(obs), 3)
            np.testing.assert_allclose(est.class_posterior.sum(axis=1), 1.0)
            right += est.predicted == c
            pos_err.append(np.linalg.norm(est.qpos[:, :3] - base_pos, axis=1).mean())
    assert right >= 5           # of 6; chance is 2
    assert np.median(pos_err) < 0.4


def test_same_seed_same_estimate(body, trained):
    m = synthetic_demos(body, "wave", 1, np.random.default_rng(3), seconds=0.6)[0]
    obs, _, _ = synthetic_observation(body, m, np.random.default_rng(4))
    runs = [
        Tracker(trained, body, TrackerConfig.from_dict({"tracks.particles": 50}), rng=np.random.default_rng(8)).run(obs)
        for _ in range(2)
    ]
    np.testing.assert_array_equal(runs[0].qpos, runs[1].qpos)
    np.testing.assert_array_equal(runs[0].class_posterior, runs[1].class_posterior)


def test_bad_input_is_named(body, trained):
    m = synthetic_demos(body, "squat", 1, np.random.default_rng(3), seconds=0.5)[0]
    obs, _, _ = synthetic_observation(body, m, np.random.default_rng(4))
    tracker = Tracker(trained, body, TrackerConfig.from_dict({"tracks.particles": 20}))
    bad = [f.copy() for f in obs.flows]
    bad[3][0, 1] = np.nan
    with pytest.raises(ObservationError, match="frame 3, row 0"):
        tracker.run(Observation(obs.fps, obs.intrinsics, bad))
    bad = [f.copy() for f in obs.flows]
    bad[2][1, 0] = -5.0
    with pytest.raises(ObservationError, match="outside the 640x480 image"):
        tracker.run(Observation(obs.fps, obs.intrinsics, bad))
    with pytest.raises(EngineError, match=r"tracks.particles must be in \[1, 1000000\]"):
        TrackerConfig.from_dict({"tracks.particles": 0})
    with pytest.raises(EngineError, match="nothing to estimate"):
        tracker.run(Observation(obs.fps, obs.intrinsics, [np.empty((0, 4))] * 5))
    trained_bad = MotionDatabase(n_states=10)
    trained_bad.__dict__.update({k: v for k, v in trained.__dict__.items() if k.endswith("_")})
    trained_bad.covars_ = trained.covars_[:, :5]
    with pytest.raises(EngineError, match="database covars has shape"):
        Tracker(trained_bad, body)


def test_command_line_learns_simulates_and_tracks(tmp_path):
    """train-database -> simulate -> track, through files, as a user with recorded flows would."""
    from harness.cli import main

    db, obs, est = tmp_path / "db.npz", tmp_path / "obs.npz", tmp_path / "est.npz"
    assert main(["train-database", "--out", str(db), "--classes", "walk", "squat", "--demos", "3",
                 "--states", "8"]) == 0
    assert main(["simulate", "--class", "squat", "--seed", "1", "--markers", "60", "--out", str(obs)]) == 0
    assert main(["track", str(obs), "--database", str(db), "--particles", "40", "--out", str(est)]) == 0
    with np.load(est) as z:
        T = len(Observation.load(obs))
        assert z["qpos"].shape == (T, 57) and z["class_posterior"].shape == (T, 2)
        np.testing.assert_allclose(np.linalg.norm(z["qpos"][:, 3:7], axis=1), 1.0, atol=1e-9)
    assert main(["track", str(obs), "--database", str(tmp_path / "missing.npz")]) == 2


def test_a_given_base_pose_is_kept(body, trained):
    # The ground-truth-pose baseline: recovery fits the angles at the given pose and never moves it.
    m = synthetic_demos(body, "squat", 1, np.random.default_rng(6), seconds=0.6)[0]
    obs, base_pos, base_quat = synthetic_observation(body, m, np.random.default_rng(7))
    est = Tracker(trained, body, TrackerConfig.from_dict({"tracks.particles": 20}), rng=np.random.default_rng(1)).run(
        obs, base_pose=(base_pos, base_quat))
    np.testing.assert_allclose(est.qpos[:, :3], base_pos, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(est.qpos[:, 3:7] * base_quat, axis=1)), 1.0, atol=1e-12)
    assert np.abs(est.qpos[:, 7:] - est.qpos[0, 7:]).max() > 0.01      # the angles did move


def test_track_prints_the_top_three_classes(tmp_path, capsys, body, trained):
    """`harness track` names the three most probable classes of the last frame, most probable first, with
    their probabilities (2 decimals) as stored in the estimate file."""
    import re

    from harness.cli import main

    m = synthetic_demos(body, "wave", 1, np.random.default_rng(3), seconds=0.6)[0]
    obs, _, _ = synthetic_observation(body, m, np.random.default_rng(4))
    obs_path, db_path, est_path = tmp_path / "obs.npz", tmp_path / "db.npz", tmp_path / "est.npz"
    obs.save(obs_path)
    trained.save(db_path)
    capsys.readouterr()
    assert main(["track", str(obs_path), "--database", str(db_path), "--particles", "30", "--out",
                 str(est_path)]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    named = re.findall(r"(\w+) (\d\.\d\d)", line.split("recognised ", 1)[1])
    assert len(named) == 3 and {c for c, _ in named} == set(CLASSES)
    probs = [float(p) for _, p in named]
    assert probs == sorted(probs, reverse=True)
    assert sum(probs) <= 1.0 + 3 * 0.005          # each printed value is rounded to 2 decimals
    with np.load(est_path) as z:
        final = dict(zip(z["classes"], z["class_posterior"][-1]))
    assert [f"{final[c]:.2f}" for c, _ in named] == [p for _, p in named]
