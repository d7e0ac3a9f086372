"""The engine's loop against independent computations: the batched weighing against a per-track, per-class
loop; the prune and merge rule; the spawn and its fallback; live stepping against ``run``; the padding of the
frames before the first flows and before a track's first record; the given-pose source."""

import copy

import numpy as np
import pytest

from engine_fixtures import synthetic_demos, synthetic_observation
from harness import geometry
from harness.engine import Tracker, TrackerConfig
from harness.engine.likelihood import tempered, velocity_log_likelihoods
from harness.engine.logsum import logsumexp
from harness.engine.particle_filter import ParticleCloud, camera_pitch, upright_orientations
from harness.engine.pose_source import GivenPose, ParticleTracks, mixture_pairs
from harness.engine.records import FrameRecord, TrackRecord, causal_estimate, track_path
from harness.engine.recognition import Recognizer
from harness.engine.track import Track, prune_and_merge, turned
from harness.engine.transform import PointDistributions
from harness.observation import Observation


@pytest.fixture(scope="module")
def clip(body):
    m = synthetic_demos(body, "march", 1, np.random.default_rng(3), seconds=0.5)[0]
    return synthetic_observation(body, m, np.random.default_rng(4))


def _stepped(tracker, obs, frames, **reset):
    tracker.reset(obs.intrinsics, obs.fps, **reset)
    for t in range(frames):
        tracker.step(obs.flows[t])


def test_batched_weighing_equals_a_loop_over_tracks_and_classes(body, trained, clip):
    """All tracks' particles and belief terms in one kernel call give, per track, exactly the per-particle
    ``log sum_c w_c p(y | x, c)`` of a loop over tracks and terms, each term projected on its own (tracks that
    believe in several primitives: a track of one primitive has one term)."""
    obs, _, _ = clip
    cfg = TrackerConfig.from_dict({"tracks.particles": 60, "model.points": 40, "tracks.weigh_class_mass": 0.9999,
                                   "spawn.per_class": False, "tracks.weigh_by_belief": True})
    tracker = Tracker(trained, body, cfg, rng=np.random.default_rng(2))
    _stepped(tracker, obs, 6, rng=np.random.default_rng(2))
    tracks, source, scorer = tracker.tracks, tracker.source, tracker.scorer
    assert len(tracks) >= 2
    for track in tracks:
        track.predict_belief()
    frame = tracker._frames.next(obs.flows[6])
    source.predict(frame, tracks)
    batched = source.log_likelihoods(frame, tracks)
    terms = []
    for track, got in zip(tracks, batched):
        log_w, rows = track.pose_mixture(tracker.config.tracks)
        mixes = PointDistributions.concatenate([scorer.model.dists.mixture(r) for r in rows])
        terms.append(len(log_w))
        rot = geometry.to_matrix(track.cloud.quats)
        each = [scorer.frame_log_likelihood(frame, scorer.image(frame, rot, track.cloud.positions, mixes.take([c])),
                                            scorer.settings.n_eff_filter) for c in range(len(log_w))]
        np.testing.assert_allclose(got, logsumexp(np.array(each) + log_w[:, None], axis=0), rtol=1e-12, atol=1e-12)
    assert max(terms) >= 2                  # the case that needs the packing: several terms in one track
    # The packing itself: track j's pairs run term by term over all its particles.
    pose, state = mixture_pairs([2, 3], [2, 1])
    assert pose.tolist() == [0, 1, 0, 1, 2, 3, 4] and state.tolist() == [0, 0, 1, 1, 2, 2, 2]


def test_one_primitive_tracks_and_the_unrefined_recoveries_take_shortcuts_to_the_general_answers(body, trained,
                                                                                                  clip):
    """A track of one primitive has the one mixture term the general rule gives it, and the tracks recovery does
    not refine get, from one batched product, the mean angles ``recover`` would give each (its prior mean
    under the belief's most probable primitive)."""
    from harness.engine.recovery import recover
    obs, _, _ = clip
    tracker = Tracker(
        trained,
        body,
        TrackerConfig.from_dict({"tracks.particles": 60, "model.points": 40}),
        rng=np.random.default_rng(2),
    )
    _stepped(tracker, obs, 4, rng=np.random.default_rng(2))
    frame = tracker._frames.next(obs.flows[4])
    ranked = sorted(tracker.tracks, key=lambda t: -t.log_evidence)[tracker.config.recovery.tracks:]
    assert len(ranked) >= 2 and all(t.primitive is not None for t in ranked)
    for track in ranked:
        pos, quat = track.pose
        each = recover(tracker.scorer, frame, track.best_state_belief(), pos, geometry.to_matrix(quat),
                       track.pose_std, settings=tracker.config.recovery, refine=False)
        np.testing.assert_allclose(track.recovery.angles, each.angles, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(track.recovery.rotation, each.rotation)
        assert not track.recovery.refined
        shortcut = track.class_mixtures(3, 0.95)
        track.primitive, general = None, track.class_mixtures(3, 0.95)
        np.testing.assert_array_equal(shortcut[0], general[0])
        np.testing.assert_array_equal(shortcut[1], general[1])


def _track(track_id, evidence, position, heading_deg):
    t = Track(track_id, "lead", None)
    t.log_evidence = evidence
    t.place(np.asarray(position, float), upright_orientations(np.deg2rad([heading_deg]), camera_pitch(0.0))[0])
    return t


def test_prune_drops_the_far_behind_and_merge_keeps_the_better_of_two_that_met():
    a = _track(0, -100.0, [0, 0, 4], 0)
    b = _track(1, -129.9, [1, 0, 4], 90)         # within 30 nats: kept
    c = _track(2, -130.1, [2, 0, 4], 180)        # beyond 30 nats: dropped
    d = _track(3, -105.0, [0.2, 0, 4], 20)       # met a (0.2 m, 20 deg): merged into a
    e = _track(4, -101.0, [0.1, 0, 4], 60)       # near a in position, not in orientation: kept
    kept = prune_and_merge([b, c, d, a, e], prune_nats=30.0, merge_m=0.3, merge_deg=30.0)
    assert [t.id for t in kept] == [0, 4, 1]     # most evidence first
    # The better of two that met stays, whichever comes first.
    assert [t.id for t in prune_and_merge([d, a], 30.0, 0.3, 30.0)] == [0]


def test_spawn_takes_each_orientations_own_particles_or_the_leads_turned(body, trained):
    cfg = TrackerConfig.from_dict({"tracks.particles": 50, "spawn.turns": (90.0, 180.0), "spawn.twin": False})
    tracker = Tracker(trained, body, cfg)
    source = tracker.particle_tracks(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    n = 200
    pos = np.array([0.0, 0.5, 4.0]) + rng.normal(0, 0.1, (n, 3))
    heading = np.where(np.arange(n) < 140, 0.3, 0.3 + np.pi) + rng.normal(0, 0.02, n)   # a mode and its half turn
    quats = upright_orientations(heading, camera_pitch(0.1))
    weights = np.where(np.arange(n) < 140, 2.0, 1.0)           # the first mode is the heavier: the lead
    wide = ParticleCloud(pos, quats, np.log(weights / weights.sum()))
    lead, quarter, half = source.spawn(wide, None)
    assert (lead.origin, quarter.origin, half.origin) == ("lead", "turn+90", "turn+180")
    assert len(lead.cloud) == len(quarter.cloud) == len(half.cloud) == cfg.tracks.particles // 3
    rows = {tuple(p): i for i, p in enumerate(pos)}
    # The half turn has particles of its own (60 of 200, many effective ones): their own poses.
    own = [rows[tuple(p)] for p in half.cloud.positions]
    assert min(own) >= 140
    np.testing.assert_array_equal(half.cloud.quats, quats[own])
    # Nothing is near the quarter turn: the lead's particles, each turned by 90 degrees about its own vertical.
    parents = [rows[tuple(p)] for p in quarter.cloud.positions]
    assert max(parents) < 140
    np.testing.assert_allclose(np.abs(np.sum(quarter.cloud.quats * turned(quats[parents], np.pi / 2), axis=1)), 1.0,
                               atol=1e-12)


def test_stepping_frame_by_frame_gives_runs_estimate_with_leading_empty_frames(body, trained, clip):
    """The live interface: ``reset`` + ``step`` with the camera's values, frame by frame, from frames without
    flows on, equals ``run``; the frames before the first flows take the first estimate."""
    obs, _, _ = clip
    flows = [np.empty((0, 4))] * 3 + list(obs.flows)
    padded = Observation(obs.fps, obs.intrinsics, flows)
    cfg = TrackerConfig.from_dict({"tracks.particles": 40, "model.points": 40})
    whole = Tracker(trained, body, cfg, rng=np.random.default_rng(9)).run(padded)
    live = Tracker(trained, body, cfg)
    live.reset(padded.intrinsics, padded.fps, np.random.default_rng(9))
    for f in flows:
        live.step(f, None, None, None)
    est = live.result()
    for name in ("qpos", "class_posterior", "joint_posterior", "filter_pos", "n_tracks"):
        np.testing.assert_array_equal(getattr(est, name), getattr(whole, name))
    np.testing.assert_array_equal(est.offline.qpos, whole.offline.qpos)
    first = 4                                   # frames 0-3 have no flow (frame 0 of every clip is empty)
    np.testing.assert_array_equal(est.qpos[:first], np.repeat(est.qpos[first:first + 1], first, axis=0))
    np.testing.assert_array_equal(est.class_posterior[:first], np.repeat(est.class_posterior[first:first + 1], first,
                                                                         axis=0))
    assert np.all(est.ms_per_frame[:first] == 0.0)


def _record(track_id, evidence, qpos_value, posterior):
    return TrackRecord(track_id, f"t{track_id}", evidence, np.full(3, qpos_value), np.array([1.0, 0, 0, 0]),
                       np.full(57, qpos_value), np.asarray(posterior, float))


def test_records_pad_with_the_first_estimate_and_the_known_pose():
    """Frames before the first flows take the first estimate, with the base at the pose the source knew; a
    track that started late is padded with its first configuration (the offline path)."""
    known = (np.array([7.0, 8.0, 9.0]), np.array([0.0, 1.0, 0.0, 0.0]))
    post = [[0.25, 0.25], [0.25, 0.25]]
    records = [FrameRecord(0, (), known, 0.0), FrameRecord(1, (), None, 0.0),
               FrameRecord(2, (_record(0, -1.0, 1.0, post),), None, 5.0),
               FrameRecord(3, (_record(0, -3.0, 2.0, post), _record(1, -2.0, 3.0, [[0.5, 0.5], [0, 0]])), None, 5.0)]
    est = causal_estimate(records, np.array(["a", "b"]), {})
    np.testing.assert_array_equal(est.qpos[0, :7], np.r_[known[0], known[1]])
    np.testing.assert_array_equal(est.qpos[0, 7:], np.full(50, 1.0))
    np.testing.assert_array_equal(est.qpos[1], np.full(57, 1.0))
    np.testing.assert_array_equal(est.qpos[3], np.full(57, 3.0))          # the leader: most evidence
    share = np.exp([-3.0, -2.0]) / np.exp([-3.0, -2.0]).sum()
    np.testing.assert_allclose(est.class_posterior[3], share[0] * np.array([0.5, 0.5]) + share[1] * np.array([1.0, 0]))
    assert est.leader.tolist() == ["t0", "t0", "t0", "t1"]
    qpos, pos, _ = track_path(records, 1)
    np.testing.assert_array_equal(qpos[:, 7:], np.full((4, 50), 3.0))
    np.testing.assert_array_equal(qpos[0, :3], known[0])                  # the known base, where known
    np.testing.assert_array_equal(qpos[1:, :3], np.full((3, 3), 3.0))
    np.testing.assert_array_equal(pos, np.full((4, 3), 3.0))


def test_the_given_pose_source_holds_the_pose_and_recovery_moves_only_the_angles(body, trained, clip):
    obs, base_pos, base_quat = clip
    tracker = Tracker(trained, body, TrackerConfig.from_dict({"tracks.particles": 20, "model.points": 40}))
    source = GivenPose(tracker.scorer, tracker.config.belief, base_pos, base_quat)
    tracker.reset(obs.intrinsics, obs.fps, source=source)
    for f in obs.flows:
        tracker.step(f)
    est = tracker.result()
    assert est.leader.tolist() == ["given"] * len(obs) and np.all(est.n_tracks == 1)
    np.testing.assert_array_equal(est.qpos[:, :3], base_pos)
    np.testing.assert_array_equal(est.filter_pos[1:], base_pos[1:])
    assert isinstance(tracker.tracks[0].recognizer, Recognizer) and tracker.tracks[0].cloud is None


def test_recognition_scores_velocities_given_positions_at_a_tracked_pose_and_flows_at_a_given_one(body, trained,
                                                                                                clip):
    """``recognise_velocities``: a tracked pose's recognition step folds in the tempered log-likelihoods of the
    flows' velocities given their positions; at a given pose (no pose error) those of the flows themselves, so
    the ground-truth-pose baseline does not depend on the setting."""
    obs, base_pos, base_quat = clip
    tracker = Tracker(trained, body, TrackerConfig.from_dict({"tracks.particles": 20, "model.points": 40}))
    scorer = tracker.scorer
    _stepped(tracker, obs, 3)
    frame = tracker._frames.next(obs.flows[3])
    rot = geometry.to_matrix(base_quat[3][None])
    rec = Recognizer(trained, tracker.config.belief.start_spread, tracker.config.belief.prune)
    states = np.flatnonzero(rec.active().ravel())
    img = scorer.image(frame, np.repeat(rot, len(states), axis=0), np.repeat(base_pos[3][None], len(states), axis=0),
                       scorer.model.dists, states)
    n_eff = scorer.settings.n_eff_recognition
    velocities = tempered(velocity_log_likelihoods(frame.flows, img, scorer.flow_model(frame),
                                                   open_mask=frame.open), n_eff)
    flows = scorer.frame_log_likelihood(frame, img, n_eff)
    assert np.abs(velocities - flows).max() > 1.0          # the two rules differ on this frame
    for pose_given, expected in ((False, velocities), (True, flows)):
        r = copy.deepcopy(rec)
        gained = scorer.recognise(frame, [r], base_pos[3][None], base_quat[3][None], pose_given=pose_given)[0]
        log_b = np.zeros(rec.log_alpha.size)
        log_b[states] = expected
        np.testing.assert_allclose(gained, copy.deepcopy(rec).update(log_b.reshape(rec.log_alpha.shape)), rtol=1e-12)
    runs = [
        Tracker(
            trained,
            body,
            TrackerConfig.from_dict({"tracks.particles": 20, "model.points": 40, "likelihood.recognise_velocities": v}),
        ).run(obs, base_pose=(base_pos, base_quat))
        for v in (True, False)
    ]
    np.testing.assert_array_equal(runs[0].class_posterior, runs[1].class_posterior)


def _belief_over_two_primitives(trained, rng):
    """A recognizer of the small database holding a random belief over its first two primitives only, with
    pruning that leaves some states inactive."""
    rec = Recognizer(trained, prune=1e-2).restrict([0, 1])
    C, K = rec.log_alpha.shape
    log_alpha = np.where(np.arange(C)[:, None] < 2, rng.normal(0.0, 3.0, (C, K)), -np.inf)
    rec.log_alpha = log_alpha - logsumexp(log_alpha.ravel())
    return rec


def test_a_track_of_several_primitives_weighs_its_pose_under_every_primitive_alike(trained, rng):
    """Without ``weigh_by_belief``, a track that believes several primitives weighs its particles under one
    term: each possible primitive's own belief over its active states, the primitives weighed alike. The term
    does not move when only the class belief does (each primitive's log-alpha shifted by a constant); with
    ``weigh_by_belief`` it is the belief's top primitives, which do move."""
    rec = _belief_over_two_primitives(trained, rng)
    track = Track(0, "lead", rec)
    log_w, rows = track.pose_mixture(TrackerConfig().tracks)
    C, K = rec.log_alpha.shape
    blocks = rows.reshape(C, K)
    expect = np.where(rec.active(), rec.state_posterior, 0.0)[:2]
    expect /= expect.sum(axis=1, keepdims=True)
    np.testing.assert_array_equal(log_w, [0.0])
    np.testing.assert_allclose(blocks[:2], 0.5 * expect, rtol=1e-12)
    assert not blocks[2:].any()
    assert (~rec.active()[:2] <= (blocks[:2] == 0)).all()      # inactive states weigh nothing
    shifted = Track(1, "lead", copy.copy(rec))       # a shallow copy is a snapshot (Recognizer.log_alpha)
    shifted.recognizer.log_alpha = rec.log_alpha + np.array([-4.0, 2.0] + [0.0] * (C - 2))[:, None]
    assert not np.allclose(shifted.recognizer.class_posterior, rec.class_posterior)
    np.testing.assert_allclose(shifted.pose_mixture(TrackerConfig().tracks)[1], rows, rtol=1e-12, atol=1e-15)
    by_belief = TrackerConfig.from_dict({"tracks.weigh_by_belief": True, "tracks.weigh_class_mass": 0.9999}).tracks
    assert not np.allclose(shifted.pose_mixture(by_belief)[0], track.pose_mixture(by_belief)[0])



def test_a_copied_belief_is_a_snapshot_and_new_beliefs_are_independent(body, trained):
    """``copy.copy`` of a belief (each track's snapshot every frame) keeps the belief it was taken at while the
    original moves on, and moved by the same frames gives the same numbers; the beliefs a pose source hands its new
    tracks (``ParticleTracks.new_belief``, copies of one) equal a newly built belief and do not share changes; a
    track of one primitive weighs its particles under that primitive's active states alone."""
    from harness.engine.switching import SwitchingRecognizer
    from harness.engine.track import new_recognizer

    rng = np.random.default_rng(5)
    for rec in (Recognizer(trained, 0.05, 1e-4), SwitchingRecognizer(trained, 0.02, 0.05, 1e-4)):
        frames = rng.normal(-20.0, 5.0, (3, *rec.log_alpha.shape))
        rec.predict()
        rec.update(frames[0])
        snap = copy.copy(rec)
        assert type(snap) is type(rec)
        kept = snap.log_alpha.copy(), snap.posterior.copy(), snap.active().copy()
        for log_b in frames[1:]:
            rec.predict()
            rec.update(log_b)
        assert not np.allclose(rec.log_alpha, kept[0])
        for got, expect in zip((snap.log_alpha, snap.posterior, snap.active()), kept):
            np.testing.assert_array_equal(got, expect)
        for log_b in frames[1:]:
            snap.predict()
            snap.update(log_b)
        np.testing.assert_array_equal(snap.log_alpha, rec.log_alpha)
        np.testing.assert_array_equal(snap.class_posterior, rec.class_posterior)

    cfg = TrackerConfig()
    source = Tracker(trained, body, cfg).particle_tracks(np.random.default_rng(0))
    a, b, fresh = source.new_belief(), source.new_belief(), new_recognizer(trained, cfg.belief)
    for got in (a, b):
        np.testing.assert_array_equal(got.log_alpha, fresh.log_alpha)
        np.testing.assert_array_equal(got.posterior, fresh.posterior)
        np.testing.assert_array_equal(got.active(), fresh.active())
    a.restrict([1])
    a.predict()
    a.update(rng.normal(-20.0, 5.0, a.log_alpha.shape))
    np.testing.assert_array_equal(b.log_alpha, fresh.log_alpha)
    np.testing.assert_array_equal(b.class_posterior, fresh.class_posterior)
    log_w, rows = Track(0, "walk/lead", a, primitive=1).pose_mixture(cfg.tracks)
    expect = np.zeros(a.log_alpha.shape)
    expect[1] = np.where(a.active()[1], a.posterior[1], 0.0)
    np.testing.assert_array_equal(log_w, [0.0])
    np.testing.assert_array_equal(rows, expect.reshape(1, -1))
