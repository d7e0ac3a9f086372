"""From frames to each person's flows: background subtraction (``foreground``), people followed from frame to
frame (``people``), features on each person (``features``), in one pass over the frames.

With a region of interest (``roi``) the frames are cropped to it first and everything moving inside it is one
person (id 1): the way to follow one person the caller has singled out, and cheaper (only the region is
processed). Positions stay in the whole frame's pixels either way.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from harness.footage.features import FeatureTracker, PersonView
from harness.footage.foreground import Detections, Foreground, blobs
from harness.footage.people import PeopleFollower

MIN_SEEN = 3             # frames a blob must be followed before it is a person in the output (noise is briefer)


@dataclass
class PersonTrack:
    """One person over the clip. first, last: the first and last frame they were seen in (inclusive).
    boxes: ``{frame: (4,) x, y, w, h}`` where seen; grouped: frames spent inside a group (coasting);
    flows: ``{frame: (M, 4)}`` for every frame of ``first..last`` (``u, v`` px, ``du, dv`` px/s, whole-frame
    pixels)."""

    id: int
    first: int
    last: int = -1
    boxes: dict[int, np.ndarray] = field(default_factory=dict)
    grouped: set[int] = field(default_factory=set)
    flows: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return self.last - self.first + 1

    def height_px(self) -> float:
        """Median height of the person's box, px."""
        return float(np.median([b[3] for b in self.boxes.values()]))

    def speed(self, fps: float) -> float:
        """How fast the person's feet (the bottom centre of their box) move over the image, in their own
        heights per second: the median over every pair of boxes one second apart (a walker at 1.4 m/s seen
        side-on makes about 0.8; one walking along the line of sight less; someone standing about 0.05, the
        jitter of the box)."""
        frames = np.array(sorted(self.boxes))
        boxes = np.array([self.boxes[t] for t in frames])
        feet = boxes[:, :2] + boxes[:, 2:] * [0.5, 1.0]
        lag = max(1, int(round(fps)))
        later = np.searchsorted(frames, frames + lag)
        pair = later < len(frames)
        pair[pair] &= frames[later[pair]] == frames[pair] + lag
        if not pair.any():
            return float("nan")
        step = np.linalg.norm(feet[later[pair]] - feet[pair], axis=1)
        return float(np.median(step) / max(self.height_px(), 1.0))

    def frame_flows(self) -> list[np.ndarray]:
        """Flows of frames ``first..last`` in order; the first frame is empty (the observation format's frame 0
        has no predecessor)."""
        out = [self.flows.get(t, np.empty((0, 4))) for t in range(self.first, self.last + 1)]
        if out:
            out[0] = np.empty((0, 4))
        return out


@dataclass
class FollowResult:
    """Every person followed in a clip, the clip's size and length, and the wall time (s) the following took
    (background model, blobs, assignment, features; reading the frames not included)."""

    fps: float
    width: int
    height: int
    n_frames: int
    people: list[PersonTrack]
    seconds: float


def _crop(frame: np.ndarray, roi: tuple[int, int, int, int] | None) -> np.ndarray:
    if roi is None:
        return frame
    x, y, w, h = roi
    return frame[y:y + h, x:x + w]


def follow_people(frames: Iterable[np.ndarray], fps: float, background: list[np.ndarray],
                  roi: tuple[int, int, int, int] | None = None,
                  progress: Callable[[int], None] | None = None) -> FollowResult:
    """Follow the people of ``frames`` (BGR ``(H, W, 3) uint8``, in order) at ``fps``.

    background: frames to learn the background from before the pass (an empty plate, or frames spread over
    the clip: ``reader.sample_frames``). roi: ``(x, y, w, h)`` px inside the frame, or None for everyone.
    progress: called with each frame's index. Deterministic: the same frames give the same result.
    """
    import cv2

    seconds = 0.0
    t0 = time.perf_counter()
    fg = Foreground(fps)
    fg.learn([_crop(f, roi) for f in background])
    follower = PeopleFollower(fps)
    features = FeatureTracker(fps)
    offset = np.zeros(2) if roi is None else np.array(roi[:2], float)
    tracks: dict[int, PersonTrack] = {}
    seconds += time.perf_counter() - t0
    n = 0
    width = height = 0
    for t, frame in enumerate(frames):
        height, width = frame.shape[:2]
        t0 = time.perf_counter()
        image = _crop(frame, roi)
        det = blobs(fg.mask(image))
        views = _roi_views(det) if roi is not None else _people_views(follower, t, det)
        flows = features.step(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), det.labels, views)
        for i, view in views.items():
            track = tracks.setdefault(i, PersonTrack(i, t))
            if view.labels:
                track.boxes[t] = view.box + np.concatenate([offset, [0, 0]])
                track.last = t
            else:
                track.grouped.add(t)
            if len(flows[i]):
                track.flows[t] = flows[i] + np.concatenate([offset, [0, 0]])
        seconds += time.perf_counter() - t0
        n = t + 1
        if progress is not None:
            progress(t)
    people = []
    for track in tracks.values():
        if len(track.boxes) < MIN_SEEN:
            continue
        track.flows = {t: f for t, f in track.flows.items() if t <= track.last}
        track.grouped = {t for t in track.grouped if t <= track.last}
        people.append(track)
    return FollowResult(float(fps), width, height, n, people, seconds)


def _people_views(follower: PeopleFollower, t: int, det: Detections) -> dict[int, PersonView]:
    """Each followed person's blobs and box this frame (the union of their blobs; the prediction when
    grouped)."""
    assignment = follower.update(t, det.boxes)
    views: dict[int, PersonView] = {}
    for i in np.unique(assignment.owner[assignment.owner >= 0]):
        mine = np.flatnonzero(assignment.owner == i)
        views[int(i)] = PersonView(tuple(int(k) + 1 for k in mine), _union_box(det.boxes[mine]))
    for i in assignment.grouped:
        views[i] = PersonView((), follower.people[i].predicted(t))
    return views


def _roi_views(det: Detections) -> dict[int, PersonView]:
    """Everything moving in the region is person 1."""
    if not len(det):
        return {}
    return {1: PersonView(tuple(range(1, len(det) + 1)), _union_box(det.boxes))}


def _union_box(boxes: np.ndarray) -> np.ndarray:
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    lo = boxes[:, :2].min(axis=0)
    hi = (boxes[:, :2] + boxes[:, 2:]).max(axis=0)
    return np.concatenate([lo, hi - lo])
