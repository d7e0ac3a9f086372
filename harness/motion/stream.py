"""Streams: one performance of several primitives in a row, with a label per frame.

A ``Stream`` is a ``Motion`` (label ``"stream"``) and ``labels`` ``(T,)``: the primitive performed in each
frame, or ``"transition"`` between two primitives. Two sources:

**Procedural** (``procedural_stream``): a random sequence of primitives from the performer, by one subject.
The generator draws the number of primitives, their order (never the same primitive twice in a row), each
demonstration (its own durations, tempo, rests and style, ``performer.demonstrations``) and each transition's
length. Consecutive demonstrations overlap by the transition window of ``W`` frames, in which the last ``W``
frames of the one and the first ``W`` of the next are blended with a minimum-jerk weight ``w`` rising from 0
to 1 (frames labelled ``transition``):

- angles ``(1 - w) theta_a + w theta_b``; base orientation: the heading turns about the vertical by the
  weight and the tilt is slerped;
- base position: horizontally, the base moves by the blend of the two demonstrations' own steps (so its speed
  never exceeds theirs); vertically, the blended pose is grounded (``harness.body.grounding``: the lowest foot
  point on the floor) plus the blend of each demonstration's own height above its grounding (flight).

At ``w = 0`` and ``w = 1`` this is the demonstration itself, so the base and the feet are continuous into and
out of the window (a test bounds the jumps). Inside the window the feet may slide a little, as in the
transitions of motion graphs (Kovar, Gleicher and Pighin, "Motion graphs", SIGGRAPH 2002: linear blending of
the root, spherical blending of the joints, no foot-plant clean-up).

Each demonstration is placed by a turn about the vertical and a shift. It continues the heading of the one
before, turned by the smallest multiple of ``TURN_STEP_DEG`` (at most ``MAX_TURN_DEG``) that keeps its path
within ``STAGE_RADIUS`` of where the stream started, else by the one that strays least (a performer in front
of a robot turns back instead of walking out of view; walks of about 3 m still take it up to about 2.5 m
away). The turn happens during the transition, which is lengthened to turn at most ``TURN_RATE_DEG_S``.

**Captured** (``capture_stream``): the frames of one capture take from its first labelled manifest row to its
last, retargeted as one motion; frames inside a row carry its class, frames between rows are ``transition``
(the manifest parser is ``harness.motion.captures.read_manifest``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness import geometry
from harness.body import BodyModel, nominal_body
from harness.body.grounding import ground
from harness.errors import HarnessError
from harness.io import save_npz_atomic
from harness.motion.bvh import load_bvh
from harness.motion.captures import MANIFEST_NAME, CaptureRow, CaptureSetError, read_manifest, retarget_rows
from harness.motion.motion import Motion, MotionError
from harness.motion.performer import CLASSES, demonstrations

TRANSITION = "transition"
STREAM_LABEL = "stream"
PRIMITIVES = (3, 6)              # primitives per procedural stream, inclusive range
TRANSITION_S = (0.3, 0.6)        # s, range of a transition window's length
MIN_CORE_FRAMES = 5              # frames of a demonstration left to its own label between its two windows
STAGE_RADIUS = 1.5               # m, the performer's path stays about this close to its start
TURN_STEP_DEG = 15.0             # candidate turns at a transition are multiples of this ...
MAX_TURN_DEG = 90.0              # ... up to this much
TURN_RATE_DEG_S = 180.0          # a transition that turns lasts at least |turn| / this (a brisk turn on the spot)


class StreamError(HarnessError):
    """Bad input to a stream: parameters out of their domain, a take without labelled rows."""


@dataclass(frozen=True)
class Segment:
    """Frames ``[start, stop)`` that carry ``label``."""

    label: str
    start: int
    stop: int


def label_segments(labels) -> list[Segment]:
    """The runs of equal labels of a per-frame sequence, in order."""
    labels = np.asarray(labels)
    if len(labels) == 0:
        return []
    edges = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.concatenate([[0], edges])
    stops = np.concatenate([edges, [len(labels)]])
    return [Segment(str(labels[a]), int(a), int(b)) for a, b in zip(starts, stops)]


@dataclass(frozen=True)
class Stream:
    """A performance of several primitives: ``motion`` (T frames) and ``labels`` ``(T,)`` str, a primitive's
    name or ``TRANSITION`` per frame."""

    motion: Motion
    labels: np.ndarray

    def __post_init__(self):
        labels = np.asarray(self.labels, dtype=str)
        if labels.shape != (self.motion.n_frames,):
            raise StreamError(f"a stream needs one label per frame ({self.motion.n_frames}), got {labels.shape}")
        labels.setflags(write=False)
        object.__setattr__(self, "labels", labels)

    @property
    def segments(self) -> list[Segment]:
        return label_segments(self.labels)

    @property
    def primitives(self) -> list[str]:
        """The primitives in order of performance (transitions left out)."""
        return [s.label for s in self.segments if s.label != TRANSITION]

    def save(self, path: str | Path) -> None:
        m = self.motion
        save_npz_atomic(path, {"qpos": np.asarray(m.qpos), "fps": np.array(m.fps), "label": np.array(m.label),
                               "subject": np.array(m.subject), "demo": np.array(m.demo),
                               "source": np.array(m.source), "labels": self.labels})

    @classmethod
    def load(cls, path: str | Path) -> "Stream":
        try:
            with np.load(path, allow_pickle=False) as z:
                motion = Motion(qpos=z["qpos"], fps=float(z["fps"]), label=str(z["label"]),
                                subject=str(z["subject"]), demo=str(z["demo"]), source=str(z["source"]))
                return cls(motion, z["labels"].astype(str))
        except FileNotFoundError:
            raise StreamError(f"{path}: no such stream file") from None
        except (KeyError, ValueError, OSError, MotionError) as exc:
            raise StreamError(f"{path}: not a stream file ({type(exc).__name__})") from None


# --- procedural streams ----------------------------------------------------------------------------------

def _min_jerk(s: np.ndarray) -> np.ndarray:
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


@dataclass(frozen=True)
class _Part:
    """One demonstration as the stream uses it: its own base, its height above its grounding (flight), and its
    placement (turn ``yaw`` about z, then ``shift`` in xy)."""

    motion: Motion
    lift: np.ndarray            # (T,) m, base height above the grounded height
    yaw: float = 0.0
    shift: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))

    def quats(self, frames: slice | np.ndarray) -> np.ndarray:
        q = self.motion.base_quat[frames]
        return geometry.multiply(geometry.yaw(np.full(len(q), self.yaw)), q)

    def xy(self, frames: slice | np.ndarray) -> np.ndarray:
        return self._turn(self.motion.base_pos[frames, :2]) + self.shift

    def steps(self, frames: np.ndarray) -> np.ndarray:
        """Base xy displacement ``(len(frames), 2)`` into each of ``frames`` from the frame before (zero at the
        first frame), placed."""
        frames = np.asarray(frames)
        pos = self.motion.base_pos[:, :2]
        return self._turn(np.where((frames > 0)[:, None], pos[frames] - pos[np.maximum(frames - 1, 0)], 0.0))

    def _turn(self, v: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return v @ np.array([[c, s], [-s, c]])


def _part(body: BodyModel, motion: Motion) -> _Part:
    return _Part(motion, motion.base_pos[:, 2] - ground(body, motion.angles, motion.base_quat).height)


def _turn_for(part: _Part, heading: float, at: np.ndarray, radius: float) -> float:
    """The yaw that starts ``part`` on ``heading`` turned by the smallest multiple of ``TURN_STEP_DEG`` keeping
    its path (started at ``at``) within ``radius`` of the origin; else the one that strays least."""
    base = heading - float(geometry.heading(part.motion.base_quat[0]))
    path = part.motion.base_pos[:, :2] - part.motion.base_pos[0, :2]
    k = int(MAX_TURN_DEG // TURN_STEP_DEG)
    turns = np.deg2rad(TURN_STEP_DEG) * np.array(sorted(range(-k, k + 1), key=abs))
    stray = []
    for turn in turns:
        c, s = np.cos(base + turn), np.sin(base + turn)
        reach = np.linalg.norm(at + path @ np.array([[c, s], [-s, c]]), axis=1).max()
        if reach <= radius:
            return base + turn
        stray.append(reach)
    return base + turns[int(np.argmin(stray))]


def _blend_orientations(qa: np.ndarray, qb: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Base orientations ``(W, 4)`` from ``qa`` to ``qb`` by weights ``w`` ``(W,)``: the heading turns about the
    vertical (the shorter way) and the tilt is slerped apart from it. (A plain slerp between orientations half a
    turn apart may take its axis from their small tilts and tumble the body.)"""
    ha, hb = geometry.heading(qa), geometry.heading(qb)
    tilt_a = geometry.multiply(geometry.yaw(-ha), qa)
    tilt_b = geometry.multiply(geometry.yaw(-hb), qb)
    diff = hb - ha
    ref = np.arctan2(np.sin(diff).mean(), np.cos(diff).mean())      # one way round for the whole window
    turn = ref + (diff - ref + np.pi) % (2.0 * np.pi) - np.pi
    return geometry.multiply(geometry.yaw(ha + w * turn), geometry.slerp(tilt_a, tilt_b, w))


def _blend(body: BodyModel, a: _Part, b: _Part, window: int, start_xy: np.ndarray) -> tuple[np.ndarray, ...]:
    """The ``window`` transition frames between the end of ``a`` and the start of ``b`` (both placed): angles
    ``(W, 50)``, base quaternions ``(W, 4)`` and positions ``(W, 3)``. ``start_xy``: the base xy of the frame
    before the window (``a``'s)."""
    n_a = a.motion.n_frames
    fa = np.arange(n_a - window, n_a)
    fb = np.arange(window)
    w = _min_jerk(np.arange(1, window + 1) / (window + 1))
    angles = (1.0 - w[:, None]) * a.motion.angles[fa] + w[:, None] * b.motion.angles[fb]
    quats = _blend_orientations(a.quats(fa), b.quats(fb), w)
    xy = start_xy + np.cumsum((1.0 - w[:, None]) * a.steps(fa) + w[:, None] * b.steps(fb), axis=0)
    z = ground(body, angles, quats).height + (1.0 - w) * a.lift[fa] + w * b.lift[fb]
    return angles, quats, np.column_stack([xy, z])


def procedural_stream(rng: np.random.Generator, classes: tuple[str, ...] | list[str] | None = None,
                      primitives: tuple[int, int] = PRIMITIVES, transition_s: tuple[float, float] = TRANSITION_S,
                      fps: float = 30.0, subject: int | None = None, body: BodyModel | None = None,
                      demo: str = "0", left: float | None = None) -> Stream:
    """A random stream of ``primitives[0]..primitives[1]`` primitives drawn from ``classes`` (default: all
    of the performer's), performed by ``subject`` (default: drawn in [0, 1000)); see the module docstring.
    Everything is drawn from ``rng`` in a fixed order: count, order, subject, then per primitive its
    demonstration and per transition its length. ``left``: every primitive's left share (``performer.perform``)."""
    classes = tuple(CLASSES if classes is None else classes)
    lo, hi = primitives
    if not (isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer)) and 2 <= lo <= hi):
        raise StreamError(f"primitives must be [min, max] integers with 2 <= min <= max, got {list(primitives)}")
    if len(set(classes)) < 2:
        raise StreamError(f"a stream needs at least two distinct classes, got {list(classes)}")
    t_lo, t_hi = transition_s
    if not (np.isfinite(t_lo) and np.isfinite(t_hi) and 0 < t_lo <= t_hi):
        raise StreamError(f"transition_s must be [min, max] seconds with 0 < min <= max, got {list(transition_s)}")
    body = nominal_body() if body is None else body
    n = int(rng.integers(lo, hi + 1))
    order = [str(rng.choice(classes))]
    while len(order) < n:
        order.append(str(rng.choice([c for c in classes if c != order[-1]])))
    if subject is None:
        subject = int(rng.integers(0, 1000))
    motions, windows = [], []
    for i, label in enumerate(order):
        motions.append(demonstrations(label, 1, rng, fps=fps, subject=subject, body=body, left=left)[0])
        if i:
            windows.append(int(round(rng.uniform(t_lo, t_hi) * fps)))
    return join(motions, windows, body, demo)


def join(motions: list[Motion], windows: list[int], body: BodyModel | None = None, demo: str = "0") -> Stream:
    """One stream of the demonstrations ``motions`` (one frame rate), each labelled by its ``label``, joined by
    transitions of ``windows[i]`` frames between ``motions[i]`` and ``motions[i + 1]`` (see the module
    docstring). A window is lengthened to turn at most ``TURN_RATE_DEG_S``, and shortened to leave each
    demonstration it joins room for a window at its other end and ``MIN_CORE_FRAMES`` of its own."""
    if len(motions) < 1 or len(windows) != len(motions) - 1:
        raise StreamError(f"join needs n >= 1 motions and n - 1 windows, got {len(motions)} and {len(windows)}")
    fps = motions[0].fps
    if any(m.fps != fps for m in motions):
        raise StreamError(f"motions of one stream must share one frame rate, got {sorted({m.fps for m in motions})}")
    body = nominal_body() if body is None else body
    parts = [_part(body, m) for m in motions]
    windows = list(windows)
    angles, quats, pos, labels = [], [], [], []
    head = 0                                     # first frame of the current part not yet emitted
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if not last:
            # Place the next part's heading first: a turn lengthens the window.
            nxt = parts[i + 1]
            end = slice(part.motion.n_frames - 1, None)
            heading = float(geometry.heading(part.quats(end)[0]))
            nxt = dataclasses.replace(nxt, yaw=_turn_for(nxt, heading, part.xy(end)[0], STAGE_RADIUS))
            turn = abs((nxt.yaw + float(geometry.heading(nxt.motion.base_quat[0])) - heading + np.pi)
                       % (2 * np.pi) - np.pi)
            room = min((m.n_frames - MIN_CORE_FRAMES) // 2 for m in (part.motion, nxt.motion))
            wanted = max(int(windows[i]), int(np.ceil(np.rad2deg(turn) / TURN_RATE_DEG_S * fps)))
            windows[i] = max(1, min(wanted, room))
        stop = part.motion.n_frames - (0 if last else windows[i])
        core = slice(head, stop)
        angles.append(part.motion.angles[core])
        quats.append(part.quats(core))
        pos.append(np.column_stack([part.xy(core), part.motion.base_pos[core, 2]]))
        labels += [part.motion.label] * (stop - head)
        if last:
            break
        window = windows[i]
        w_angles, w_quats, w_pos = _blend(body, part, nxt, window, part.xy(slice(stop - 1, stop))[0])
        # Place the next part so that its first frame after the window continues the window's last step.
        parts[i + 1] = dataclasses.replace(nxt, shift=w_pos[-1, :2] - nxt.xy(slice(window - 1, window))[0]
                                           + nxt.shift)
        angles.append(w_angles)
        quats.append(w_quats)
        pos.append(w_pos)
        labels += [TRANSITION] * window
        head = window
    qpos = body.qpos(np.concatenate(angles), base_pos=np.concatenate(pos), base_quat=np.concatenate(quats))
    motion = Motion(qpos=qpos, fps=fps, label=STREAM_LABEL, subject=motions[0].subject, demo=demo,
                    source="procedural-stream:" + ",".join(m.label for m in motions))
    return Stream(motion, np.array(labels))


# --- captured streams ------------------------------------------------------------------------------------

def take_rows(rows: list[CaptureRow], take: str) -> list[CaptureRow]:
    """The manifest rows of one take (``take``: the file name or its stem), in frame order; overlapping
    rows of different classes are an error."""
    mine = sorted((r for r in rows if take in (r.file, Path(r.file).stem)), key=lambda r: r.start)
    if not mine:
        takes = sorted({Path(r.file).stem for r in rows})
        raise CaptureSetError(f"no manifest row of take {take!r} (takes: {', '.join(takes)})")
    for a, b in zip(mine, mine[1:]):
        if b.start < a.end and b.label != a.label:
            raise CaptureSetError(f"{b.where('start')}: frames [{b.start}, {a.end}) are labelled both "
                                  f"{a.label!r} (row {a.line}) and {b.label!r}")
    return mine


def capture_stream(directory: str | Path, take: str, manifest: str | Path | None = None, fps: float = 30.0,
                   body: BodyModel | None = None) -> Stream:
    """The labelled stream of one capture take: its frames from the first labelled row's start to the last
    row's end, retargeted as one motion at ``fps``; each frame labelled by the row it falls in (by time),
    ``transition`` between rows."""
    directory = Path(directory)
    rows = take_rows(read_manifest(Path(manifest) if manifest is not None else directory / MANIFEST_NAME), take)
    first = rows[0]
    lo, hi = first.start, max(r.end for r in rows)
    span = dataclasses.replace(first, start=lo, end=hi, label=STREAM_LABEL)
    motion, _ = retarget_rows(directory, [span], fps, body)[0]
    # BVH files carry their own frame rate; AMC rows give it in the manifest.
    source_fps = load_bvh(directory / first.file).fps if first.format == "bvh" else first.fps
    source_frame = lo + np.arange(motion.n_frames) * source_fps / fps
    labels = np.full(motion.n_frames, TRANSITION, dtype=object)
    for r in rows:
        labels[(source_frame >= r.start) & (source_frame < r.end)] = r.label
    motion = motion.replace(demo=f"{Path(first.file).stem}:{lo}-{hi}", subject=first.subject)
    return Stream(motion, labels.astype(str))
