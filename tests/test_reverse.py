"""Time reversal against independent computations: reversed flows against the backward differences of the
reversed point paths; the reversed model's point distributions against the transform of the reversed database
computed from scratch; the reversed chains' dwell and direction; the backward pass end to end."""

import numpy as np
import pytest

from engine_fixtures import synthetic_demos, synthetic_observation
from harness.engine import Tracker, TrackerConfig
from harness.engine.database import left_to_right
from harness.engine.model import EngineModel
from harness.engine.reverse import reversed_database, reversed_flows, reversed_model, reversed_start, reversed_transitions


def test_reversed_flows_pair_each_position_with_the_velocity_of_the_interval_it_ends():
    rng = np.random.default_rng(0)
    fps, T, N = 30.0, 7, 5
    paths = np.cumsum(rng.normal(0, 3, (T, N, 2)), axis=0)           # pixel paths of N points
    forward = [np.zeros((0, 4))] + [np.concatenate([paths[t], (paths[t] - paths[t - 1]) * fps], axis=1)
                                    for t in range(1, T)]
    back = reversed_flows(forward)
    assert len(back) == T and len(back[-1]) == 0
    for s in range(T - 1):
        t = T - 1 - s            # the reversed clip's frame s is time t: the point at p_t moving to p_{t-1}
        expected = np.concatenate([paths[t], (paths[t - 1] - paths[t]) * fps], axis=1)
        np.testing.assert_allclose(back[s], expected, atol=1e-9)


def test_a_left_to_right_chain_reversed_keeps_its_dwell_and_runs_the_other_way():
    a = left_to_right(5, 4.0, cyclic=False)
    r = reversed_transitions(a)
    np.testing.assert_allclose(r.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.diag(r)[1:4], np.diag(a)[1:4])
    for k in range(1, 4):
        assert r[k, k - 1] == pytest.approx(1 - a[k, k])
    assert r[0, 0] == 1.0                                            # the first state absorbs backwards
    assert r[4, 4] == pytest.approx(np.mean(np.diag(a)[:4]))         # the end rest is left backwards
    np.testing.assert_allclose(reversed_start(a), np.eye(5)[4])      # ... and the last state starts
    cyc = left_to_right(4, 3.0, cyclic=True)
    rc = reversed_transitions(cyc)
    assert rc[0, 3] == pytest.approx(1 - cyc[0, 0])                  # the wrap runs backwards too
    np.testing.assert_allclose(reversed_start(cyc), np.full(4, 0.25))


def test_the_reversed_model_is_the_transform_of_the_reversed_database(body, trained):
    model = EngineModel.build(trained, body, 40, 3)
    rev = reversed_model(model)
    direct = EngineModel.build(reversed_database(trained), body, 40, 3)
    for name in ("pos", "pos_cov", "vel", "vel_cov", "base_linear", "base_angular"):
        np.testing.assert_allclose(getattr(rev.dists, name), getattr(direct.dists, name), rtol=1e-7, atol=1e-9,
                                   err_msg=name)
    np.testing.assert_allclose(rev.db.transmat_.sum(axis=-1), 1.0)
    np.testing.assert_allclose(rev.db.startprob_.sum(axis=-1), 1.0)


def test_the_backward_pass_is_repeatable_and_covers_every_frame(body, trained):
    m = synthetic_demos(body, "march", 1, np.random.default_rng(3), seconds=0.6)[0]
    obs, _, _ = synthetic_observation(body, m, np.random.default_rng(4))
    cfg = TrackerConfig.from_dict(
        {
            "tracks.particles": 60,
            "model.points": 40,
            "spawn.turns": (),
            "spawn.factor": 2,
            "offline.backward_pass": True,
        }
    )
    one = Tracker(trained, body, cfg, rng=np.random.default_rng(5)).run(obs).offline
    two = Tracker(trained, body, cfg, rng=np.random.default_rng(5)).run(obs).offline
    np.testing.assert_array_equal(one.qpos, two.qpos)
    np.testing.assert_array_equal(one.class_posterior, two.class_posterior)
    assert one.qpos.shape == (len(obs), 57) and np.isfinite(one.qpos).all()
    np.testing.assert_allclose(one.class_posterior, np.repeat(one.class_posterior[:1], len(obs), axis=0))


def test_the_backward_starts_are_each_primitives_best_final_cloud_or_the_leaders_and_live_only_drops_the_latter():
    from harness.engine.backward import settled_starts
    from harness.engine.particle_filter import ParticleCloud
    from harness.engine.track import Track

    def track(i, primitive, evidence):
        cloud = ParticleCloud(np.full((2, 3), float(i)), np.tile([1.0, 0, 0, 0], (2, 1)), np.log([0.5, 0.5]))
        return Track(i, f"p{primitive}/lead", None, cloud, primitive=primitive, log_evidence=evidence)

    final = [track(0, 2, -50.0), track(1, 0, -10.0), track(2, 2, -20.0)]
    starts = settled_starts(final, 4)
    assert [(c, origin) for c, origin, _ in starts] == [(0, "end:lead"), (1, "end:leader"), (2, "end:lead"),
                                                         (3, "end:leader")]
    assert starts[0][2] is final[1].cloud and starts[1][2] is final[1].cloud     # the leader's cloud
    assert starts[2][2] is final[2].cloud                                       # primitive 2's best, not its first
    assert [(c, cloud) for c, _, cloud in settled_starts(final, 4, live_only=True)] == [(0, final[1].cloud),
                                                                                        (2, final[2].cloud)]


def test_backward_starts_from_one_cloud_each_hold_their_own_and_are_weighed_once(body, trained):
    """Primitives without a live track start from the same leader's cloud: each backward track gets its own copy,
    so the first frame weighs every track once, by its own primitive (before, a shared cloud was weighed by every
    holder's primitive in turn, and all holders kept the product)."""
    from types import SimpleNamespace

    from harness import geometry
    from harness.engine.backward import SettledStarts
    from harness.engine.logsum import logsumexp
    from harness.engine.particle_filter import ParticleCloud

    rng = np.random.default_rng(0)
    prior = np.log(np.full(4, 0.25))
    shared = ParticleCloud(rng.normal(size=(4, 3)), geometry.normalize(rng.normal(size=(4, 4))), prior.copy())
    tracker = Tracker(trained, body, TrackerConfig.from_dict({"model.points": 40}))
    tracks = tracker.particle_tracks(
        rng, SettledStarts, starts=[(0, "end:lead", shared), (1, "end:leader", shared)]
    ).start(SimpleNamespace(gravity=None))
    assert len({id(t.cloud) for t in tracks}) == len(tracks) >= 2
    lls = [rng.normal(size=4) for _ in tracks]
    for track, ll in zip(tracks, lls):
        track.cloud.reweight(ll)
    for track, ll in zip(tracks, lls):
        np.testing.assert_allclose(track.cloud.log_weights, prior + ll - logsumexp(prior + ll), rtol=1e-12)
    np.testing.assert_array_equal(shared.log_weights, prior)
