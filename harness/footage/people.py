"""People followed from frame to frame: the foreground blobs of each frame assigned to the people of the frame
before (``scipy.optimize.linear_sum_assignment`` on overlap and distance), with crossings handled honestly.

Per frame, each person's box is predicted at constant velocity. Then, in order:

1. **Groups**: a blob that holds most (``GROUP_SHARE``) of the predicted boxes of two or more people is
   people walking together or crossing; it is given to none of them (whose features it holds cannot be told
   from the blob), and they coast on their predictions, flagged as grouped.
2. **Assignment**: the other blobs and people, cost ``1 - IoU + DISTANCE_WEIGHT * d / h`` (``d`` the distance
   between the centres, ``h`` the predicted height), pairs with no overlap and ``d > GATE * h`` forbidden.
3. **Honest re-identification**: a person who comes out of a group keeps their identity only when the blob
   is clearly theirs (every other member of the group costs ``AMBIGUITY`` times more for it); otherwise that
   person's track ends and the blob starts a new one, so that two people who cross never swap identities
   silently.
4. **Fragments**: an unassigned blob lying mostly (``FRAGMENT_SHARE``) inside where a person seen this frame
   may be (their predicted box and their blob) is a part of them cut off by a thin obstacle (a lamp post) and
   joins them; a person whose predicted box lies almost wholly (``NESTED_SHARE``) inside an older member's of
   the same blob, moving with them (``SAME_MOTION``), was such a piece followed apart, and ends.
5. Blobs left start new people; a person not seen for ``MAX_MISSED_S`` seconds (``MAX_GROUPED_S`` while
   grouped) ends.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

GROUP_SHARE = 0.5        # a blob holding this share of two predicted boxes is a group
NESTED_SHARE = 0.8       # ... unless one box lies this much inside the other's and moves with it (within
SAME_MOTION = 0.5        # this many body heights per second): a piece of one person followed apart, not a
                         # second person (two walkers crossing differ by twice a walking pace, 1.6 heights/s)
GATE = 0.6               # a blob whose centre is farther than this x the person's height is not theirs
DISTANCE_WEIGHT = 1.0    # cost of a centre distance of one person's height, against a lost overlap of 1
AMBIGUITY = 1.5          # a re-identification must be this much cheaper than any group partner's
FRAGMENT_SHARE = 0.6     # share of a blob's box inside a person's box that makes it a fragment of them
MAX_MISSED_S = 1.0       # s a person may go unseen (behind a sign, the subtractor losing them) and continue
MAX_GROUPED_S = 4.0      # s a person may stay inside a group
VELOCITY_SMOOTHING = 0.5  # weight of the newest displacement in the velocity estimate
_FORBIDDEN = 1e6


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of boxes ``a (N, 4)`` and ``b (K, 4)`` (``x, y, w, h``): ``(N, K)``."""
    inter = _intersection(a, b)
    area_a = a[:, 2] * a[:, 3]
    area_b = b[:, 2] * b[:, 3]
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-9)


def _intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = np.asarray(a, float).reshape(-1, 4), np.asarray(b, float).reshape(-1, 4)
    w = np.minimum(a[:, None, 0] + a[:, None, 2], b[None, :, 0] + b[None, :, 2]) - np.maximum(a[:, None, 0],
                                                                                             b[None, :, 0])
    h = np.minimum(a[:, None, 1] + a[:, None, 3], b[None, :, 1] + b[None, :, 3]) - np.maximum(a[:, None, 1],
                                                                                             b[None, :, 1])
    return np.clip(w, 0, None) * np.clip(h, 0, None)


def share_inside(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Share of each box of ``a (N, 4)`` lying inside each box of ``b (K, 4)``: ``(N, K)``."""
    a = np.asarray(a, float).reshape(-1, 4)
    return _intersection(a, b) / np.maximum(a[:, 2] * a[:, 3], 1e-9)[:, None]


def centre(boxes: np.ndarray) -> np.ndarray:
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    return boxes[:, :2] + 0.5 * boxes[:, 2:]


@dataclass
class Person:
    """One followed person (state). box: last seen ``x, y, w, h`` px; velocity: of the box centre, px per
    frame; last_seen: the frame of that box; group: the ids of the people last grouped with (empty when
    alone); hits: frames seen."""

    id: int
    box: np.ndarray
    last_seen: int
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    group: frozenset = frozenset()
    hits: int = 1

    def predicted(self, t: int) -> np.ndarray:
        out = self.box.astype(float).copy()
        out[:2] += self.velocity * (t - self.last_seen)
        return out


@dataclass(frozen=True)
class Assignment:
    """One frame's result: ``owner (K,)`` the person id of each blob (-1: a group's blob, or none);
    ``grouped``: ids of the people inside a group this frame (coasting); ``ended``: ids whose track ended."""

    owner: np.ndarray
    grouped: tuple[int, ...]
    ended: tuple[int, ...]


class PeopleFollower:
    """Assigns each frame's blobs to people (state: the people being followed and the next free id)."""

    def __init__(self, fps: float):
        self.fps = float(fps)
        self.max_missed = max(1, int(round(MAX_MISSED_S * fps)))
        self.max_grouped = max(1, int(round(MAX_GROUPED_S * fps)))
        self.people: dict[int, Person] = {}
        self.next_id = 1

    def update(self, t: int, boxes: np.ndarray) -> Assignment:
        """Assign the blobs ``boxes (K, 4)`` of frame ``t`` (frames in increasing order)."""
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        owner = np.full(len(boxes), -1, dtype=int)
        ids = list(self.people)
        pred = np.array([self.people[i].predicted(t) for i in ids]).reshape(-1, 4)
        free = np.ones(len(boxes), dtype=bool)
        ended: list[int] = []
        grouped = self._groups(ids, pred, boxes, free, ended)
        alone = [k for k, i in enumerate(ids) if i in self.people and i not in grouped]
        cost = self._cost(pred[alone], boxes) if alone else np.empty((0, len(boxes)))
        cost[:, ~free] = _FORBIDDEN
        rows, cols = linear_sum_assignment(cost) if cost.size else (np.empty(0, int), np.empty(0, int))
        reach: dict[int, np.ndarray] = {}     # where each person seen this frame may have parts: prediction + blob
        for r, c in zip(rows, cols):
            if cost[r, c] >= _FORBIDDEN:
                continue
            person = self.people[ids[alone[r]]]
            if person.group and not self._clearly_theirs(person, boxes[c], t):
                ended.append(person.id)          # the blob starts a new person below
                del self.people[person.id]
                continue
            owner[c] = person.id
            free[c] = False
            reach[person.id] = _union(pred[alone[r]], boxes[c])
            self._see(person, boxes[c], t)
        self._fragments(owner, boxes, free, reach)
        for c in np.flatnonzero(free):
            owner[c] = self.next_id
            self.people[self.next_id] = Person(self.next_id, boxes[c].copy(), t)
            self.next_id += 1
        for i in list(self.people):
            p = self.people[i]
            limit = self.max_grouped if i in grouped else self.max_missed
            if t - p.last_seen > limit:
                ended.append(i)
                del self.people[i]
        return Assignment(owner, tuple(sorted(i for i in grouped if i in self.people)), tuple(sorted(ended)))

    def _groups(self, ids: list[int], pred: np.ndarray, boxes: np.ndarray, free: np.ndarray,
                ended: list[int]) -> set[int]:
        """Blobs holding several people: marked not free; their people flagged as grouped with each other.

        A member whose predicted box lies mostly inside an older member's is no second person but a piece of
        that one followed apart (a fragment that started its own track): it ends instead."""
        grouped: set[int] = set()
        if not len(ids) or not len(boxes):
            return grouped
        inside = share_inside(pred, boxes)                  # (people, blobs)
        nested = share_inside(pred, pred)                   # (people, people)
        for c in range(len(boxes)):
            members = sorted((k for k in np.flatnonzero(inside[:, c] >= GROUP_SHARE) if ids[k] in self.people),
                             key=lambda k: -self.people[ids[k]].hits)
            kept: list[int] = []
            for k in members:
                if any(nested[k, j] >= NESTED_SHARE and self._same_motion(ids[k], ids[j], pred[j, 3])
                       for j in kept):
                    ended.append(ids[k])
                    del self.people[ids[k]]
                else:
                    kept.append(k)
            if len(kept) >= 2:
                free[c] = False
                names = {ids[k] for k in kept}
                for i in names:
                    self.people[i].group = frozenset(self.people[i].group | names) - {i}
                grouped |= names
        return grouped

    def _same_motion(self, a: int, b: int, height: float) -> bool:
        """Whether people ``a`` and ``b`` move alike (within ``SAME_MOTION`` heights per second)."""
        gap = np.linalg.norm(self.people[a].velocity - self.people[b].velocity) * self.fps
        return bool(gap <= SAME_MOTION * max(height, 1.0))

    @staticmethod
    def _cost(pred: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        overlap = iou(pred, boxes)
        h = np.maximum(pred[:, 3:4], 1.0)
        dist = np.linalg.norm(centre(pred)[:, None, :] - centre(boxes)[None, :, :], axis=2) / h
        cost = 1.0 - overlap + DISTANCE_WEIGHT * dist
        return np.where((overlap > 0) | (dist <= GATE), cost, _FORBIDDEN)

    def _clearly_theirs(self, person: Person, box: np.ndarray, t: int) -> bool:
        """Whether a blob is ``person``'s rather than any group partner's still followed."""
        own = self._cost(person.predicted(t)[None], box[None])[0, 0]
        partners = [self.people[i] for i in person.group if i in self.people and i != person.id]
        for other in partners:
            if self._cost(other.predicted(t)[None], box[None])[0, 0] < AMBIGUITY * own:
                return False
        return True

    @staticmethod
    def _fragments(owner: np.ndarray, boxes: np.ndarray, free: np.ndarray, reach: dict[int, np.ndarray]) -> None:
        """Free blobs lying mostly inside where a person seen this frame may be (their predicted box and their
        blob) join that person."""
        if not reach or not free.any():
            return
        seen = list(reach)
        inside = share_inside(boxes, np.array([reach[i] for i in seen]))     # (blobs, people)
        for c in np.flatnonzero(free):
            k = int(np.argmax(inside[c]))
            if inside[c, k] >= FRAGMENT_SHARE:
                owner[c] = seen[k]
                free[c] = False

    @staticmethod
    def _see(person: Person, box: np.ndarray, t: int) -> None:
        step = (centre(box)[0] - centre(person.box)[0]) / max(t - person.last_seen, 1)
        person.velocity = (1 - VELOCITY_SMOOTHING) * person.velocity + VELOCITY_SMOOTHING * step
        person.box = box.copy()
        person.last_seen = t
        person.hits += 1
        person.group = frozenset()


def _union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lo = np.minimum(a[:2], b[:2])
    hi = np.maximum(a[:2] + a[2:], b[:2] + b[2:])
    return np.concatenate([lo, hi - lo])
