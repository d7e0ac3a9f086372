"""Streams: labels per frame, the demonstrations they are made of, and continuity at the transitions."""

import numpy as np
import pytest

from harness import geometry
from harness.body import body_origins, geom_z_range
from harness.body.grounding import foot_geoms
from harness.motion.motion import Motion
from harness.motion.performer import CLASSES, demonstrations
from harness.motion.stream import (TRANSITION, Segment, Stream, StreamError, capture_stream, join, label_segments,
                                   procedural_stream)
from tests.conftest import require_mocap

JUMP_M = 0.02           # the requirement: no jump of the base or the feet beyond 2 cm per frame at a transition
FEET = ("lfoot", "rfoot", "ltoes", "rtoes")


def _sign_aligned(q, ref):
    return q * np.sign(np.sum(q * ref, axis=-1, keepdims=True))


def placed_sources(stream: Stream, motions: list[Motion]) -> list[tuple[np.ndarray, int, Segment]]:
    """Each demonstration placed as the stream placed it (a turn about z and a shift, fitted from the first frame
    of its own segment), with the source frame of that first frame and its segment. Asserts that every frame of
    a primitive's segment is its demonstration's frame, placed."""
    segs = label_segments(stream.labels)
    cores = [s for s in segs if s.label != TRANSITION]
    windows = [s.stop - s.start for s in segs if s.label == TRANSITION]
    assert [s.label for s in cores] == [m.label for m in motions]
    out, first = [], 0
    for i, (m, seg) in enumerate(zip(motions, cores)):
        yaw = geometry.heading(stream.motion.base_quat[seg.start]) - geometry.heading(m.base_quat[first])
        q = m.qpos.copy()
        c, s = np.cos(yaw), np.sin(yaw)
        q[:, :2] = m.base_pos[:, :2] @ np.array([[c, s], [-s, c]])
        q[:, :2] += stream.motion.base_pos[seg.start, :2] - q[first, :2]
        q[:, 3:7] = geometry.multiply(geometry.yaw(np.full(len(q), yaw)), m.base_quat)
        own = q[first:first + seg.stop - seg.start].copy()
        got = stream.motion.qpos[seg.start:seg.stop]
        own[:, 3:7] = _sign_aligned(own[:, 3:7], got[:, 3:7])
        np.testing.assert_allclose(own, got, atol=1e-9)
        out.append((q, first, seg))
        first = windows[i] if i < len(windows) else 0
    return out


def _off_segment(x, a, b):
    """Distance of points ``x`` ``(N, 2)`` from the segments ``a -> b`` (each ``(N, 2)``)."""
    d = b - a
    t = np.clip(np.sum((x - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(x - (a + t[:, None] * d), axis=1)


def jumps(body, stream: Stream, motions: list[Motion]) -> dict[str, float]:
    """The largest jump at any transition, metres per frame, of:

    - ``base``: the distance of the base's horizontal step in a transition frame (or across its seams) from the
      steps the two demonstrations take there (from any blend of them);
    - ``seam``: the base's or a foot's displacement across a seam (into or out of a window) beyond its
      demonstration's own displacement there.
    """
    foot_ids = [body.body_id(n) - 1 for n in FEET]

    def points(qpos):
        return np.concatenate([qpos[:, None, :3], body_origins(body, qpos)[:, foot_ids]], axis=1)

    sources = placed_sources(stream, motions)
    p = points(stream.motion.qpos)
    worst = {"base": 0.0, "seam": 0.0}
    for i, win in enumerate(s for s in label_segments(stream.labels) if s.label == TRANSITION):
        (qa, fa, sa), (qb, _, _) = sources[i], sources[i + 1]
        frames = np.arange(win.start - 1, win.stop + 1)          # the window and the frame each side
        ia, ib = fa + frames - sa.start, frames - win.start
        a = points(qa[np.clip(ia, 0, len(qa) - 1)])
        b = points(qb[np.clip(ib, 0, len(qb) - 1)])
        da, db, ds = (np.linalg.norm(np.diff(x, axis=0), axis=-1) for x in (a, b, p[frames]))
        # Where a demonstration has no frame (before b's first, after a's last) only the other one counts.
        da[ia[1:] >= len(qa)] = 0.0
        db[ib[1:] <= 0] = 0.0
        # The base's horizontal step lies between the two demonstrations' steps (some blend of them).
        sa_, sb_, ss_ = (np.diff(x[:, 0, :2], axis=0) for x in (a, b, p[frames]))
        sa_[ia[1:] >= len(qa)] = sb_[ia[1:] >= len(qa)]
        sb_[ib[1:] <= 0] = sa_[ib[1:] <= 0]
        worst["base"] = max(worst["base"], float(_off_segment(ss_, sa_, sb_).max()))
        step_s, step_a, step_b = (np.diff(x, axis=0) for x in (p[frames], a, b))
        seam_in = np.linalg.norm(step_s[0] - step_a[0], axis=-1).max()
        seam_out = np.linalg.norm(step_s[-1] - step_b[-1], axis=-1).max()
        worst["seam"] = max(worst["seam"], float(seam_in), float(seam_out))
    return worst


def _lowest_foot(body, qpos):
    return geom_z_range(body, qpos, foot_geoms(body))[:, :, 0].min(axis=1)


@pytest.fixture(scope="module")
def joined(body):
    """Demonstrations by one subject, chosen to exercise every kind of transition: standing to travelling, a run
    into a stop, flights (jump, jumping jack) on either side, and turns."""
    rng = np.random.default_rng(11)
    order = ["squat", "walk", "run", "bow", "jump", "jumping_jack", "walk", "kick", "run", "wave"]
    motions = [demonstrations(c, 1, rng, subject=3, body=body)[0] for c in order]
    windows = [9, 12, 15, 18, 10, 14, 16, 11, 13]
    return join(motions, windows, body), motions


def test_segments_are_the_demonstrations_placed_and_labelled(joined):
    stream, motions = joined
    segs = label_segments(stream.labels)
    assert [s.label for s in segs] == sum(([m.label, TRANSITION] for m in motions), [])[:-1]
    placed_sources(stream, motions)           # asserts every primitive frame is its demonstration's, placed
    assert np.allclose(stream.motion.base_pos[0, :2], 0.0)
    assert stream.primitives == [m.label for m in motions]


def test_no_jump_of_the_base_or_the_feet_at_a_transition(body, joined):
    """Horizontally, the base moves as a blend of the two demonstrations everywhere in a transition; at the seams
    the base and the feet move as their demonstration does. (Inside a window the grounded base height may change
    faster than either demonstration's: see docs/streams.md.)"""
    stream, motions = joined
    worst = jumps(body, stream, motions)
    assert worst["base"] <= JUMP_M, worst
    assert worst["seam"] <= JUMP_M, worst


def test_the_jump_check_finds_a_jump(body, joined):
    stream, motions = joined
    win = [s for s in label_segments(stream.labels) if s.label == TRANSITION][3]      # bow to jump
    qpos = stream.motion.qpos.copy()
    qpos[(win.start + win.stop) // 2:, 0] += 0.05          # the base moved 5 cm in one frame mid-window
    worst = jumps(body, Stream(stream.motion.replace(qpos=qpos), stream.labels), motions)
    assert worst["base"] > 0.04


def test_feet_on_the_floor_in_every_transition_frame(body, joined):
    stream, motions = joined
    low = _lowest_foot(body, stream.motion.qpos)
    assert low.min() > -1e-6                                          # never through the floor
    sources = placed_sources(stream, motions)
    trans = [s for s in label_segments(stream.labels) if s.label == TRANSITION]
    grounded_both = 0
    for i, win in enumerate(trans):
        (qa, fa, sa), (qb, _, _) = sources[i], sources[i + 1]
        frames = np.arange(win.start, win.stop)
        both = (np.abs(_lowest_foot(body, qa[fa + frames - sa.start])) < 1e-6) & \
               (np.abs(_lowest_foot(body, qb[frames - win.start])) < 1e-6)
        np.testing.assert_allclose(low[frames[both]], 0.0, atol=1e-6)     # on it where both demos stand
        grounded_both += both.sum()
    assert grounded_both > 50


def test_procedural_streams_draw_count_order_and_subject_from_the_generator(body):
    seen = set()
    for seed in range(6):
        s = procedural_stream(np.random.default_rng(seed), body=body)
        prims = s.primitives
        assert 3 <= len(prims) <= 6
        assert all(a != b for a, b in zip(prims, prims[1:]))
        assert set(prims) <= set(CLASSES)
        assert s.motion.source == "procedural-stream:" + ",".join(prims)
        windows = [g.stop - g.start for g in s.segments if g.label == TRANSITION]
        assert len(windows) == len(prims) - 1 and min(windows) >= 1
        seen.add(tuple(prims))
    assert len(seen) == 6
    a = procedural_stream(np.random.default_rng(4), body=body, subject=1001)
    b = procedural_stream(np.random.default_rng(4), body=body, subject=1001)
    assert np.array_equal(a.motion.qpos, b.motion.qpos) and np.array_equal(a.labels, b.labels)
    assert a.motion.subject == "1001"


@pytest.mark.parametrize("kwargs, match", [({"primitives": (1, 3)}, "primitives"),
                                           ({"primitives": (4, 3)}, "primitives"),
                                           ({"classes": ["walk"]}, "two distinct classes"),
                                           ({"transition_s": (0.0, 0.5)}, "transition_s")])
def test_bad_stream_parameters_are_named(kwargs, match):
    with pytest.raises(StreamError, match=match):
        procedural_stream(np.random.default_rng(0), **kwargs)


def test_label_segments_by_hand():
    labels = ["walk", "walk", TRANSITION, "run", "run", "run", TRANSITION, "walk"]
    assert label_segments(labels) == [Segment("walk", 0, 2), Segment(TRANSITION, 2, 3), Segment("run", 3, 6),
                                      Segment(TRANSITION, 6, 7), Segment("walk", 7, 8)]
    assert label_segments([]) == []


def test_stream_file_round_trip(tmp_path, body):
    s = procedural_stream(np.random.default_rng(2), body=body, primitives=(2, 2))
    s.save(tmp_path / "s.npz")
    back = Stream.load(tmp_path / "s.npz")
    assert np.array_equal(back.labels, s.labels) and np.array_equal(back.motion.qpos, s.motion.qpos)
    with pytest.raises(StreamError, match="one label per frame"):
        Stream(s.motion, s.labels[:-1])
    (tmp_path / "bad.npz").write_bytes(b"x")
    with pytest.raises(StreamError, match="not a stream file"):
        Stream.load(tmp_path / "bad.npz")


def test_a_capture_take_becomes_a_labelled_stream():
    from harness.motion.captures import read_manifest

    root = require_mocap()
    rows = sorted((r for r in read_manifest(root / "MANIFEST.csv") if r.file == "13_30.amc"), key=lambda r: r.start)
    s = capture_stream(root, "13_30")
    lo, hi = rows[0].start, max(r.end for r in rows)
    assert s.motion.n_frames == int(np.floor((hi - lo - 1) / 120.0 * 30.0 + 1e-9)) + 1
    source = lo + 4 * np.arange(s.motion.n_frames)            # 120 fps captured, 30 fps retargeted
    for r in rows:
        inside = (source >= r.start) & (source < r.end)
        assert inside.any() and np.all(s.labels[inside] == r.label)
    outside = ~np.any([(source >= r.start) & (source < r.end) for r in rows], axis=0)
    assert outside.any() and np.all(s.labels[outside] == TRANSITION)
    with pytest.raises(Exception, match="no manifest row of take '99_99'"):
        capture_stream(root, "99_99")
