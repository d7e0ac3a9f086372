"""What every frame produced, as typed records, and the estimates built from them.

Per frame the tracker records each live track (``TrackRecord``: its evidence, filter pose, recovered
configuration and belief) in a ``FrameRecord``; frames before the first flows hold no tracks. From the records:

- ``causal_estimate``: frame ``t`` from frames ``<= t``. The class posterior is the evidence-weighted mixture
  ``sum_j softmax(L)_j p_j(c | y)`` of the tracks' posteriors, calibrated (``confidence``); the pose comes from
  the track with the most evidence. Frames before the first flows take the first estimate.
- ``offline_estimate`` (a post-processor over the records, for evaluation): the whole trajectory of the track
  with the most evidence at the end, smoothed, and the final posterior at every frame (one primitive per clip;
  a stream keeps its causal posteriors).

Frames before a track's first record take its first configuration; where the pose source knew the base pose
of such a frame (a given pose), the base is that pose.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from harness.engine.confidence import calibrated, class_bias
from harness.engine.estimate import Estimate, smooth_trajectory
from harness.engine.logsum import logsumexp
from harness.errors import EngineError


@dataclass(frozen=True)
class TrackRecord:
    """One track at the end of one frame: id and origin, log_evidence (nats), its filter estimate
    ``position (3,)``, ``quat (4,)``, the recovered configuration ``qpos (57,)`` and its joint posterior
    ``(C, K)`` over (primitive, state)."""

    track_id: int
    origin: str
    log_evidence: float
    position: np.ndarray
    quat: np.ndarray
    qpos: np.ndarray
    joint_posterior: np.ndarray


@dataclass(frozen=True)
class FrameRecord:
    """One frame: its live tracks in the tracker's order (none before the first flows), the base pose the
    pose source knew for it (``(position, quaternion)`` or None), and the engine's time on it (ms)."""

    index: int
    tracks: tuple[TrackRecord, ...]
    known_pose: tuple[np.ndarray, np.ndarray] | None
    ms: float

    def decision(self) -> tuple[np.ndarray, TrackRecord]:
        """The evidence-weighted mixture of the tracks' joint posteriors ``(C, K)`` and the leading track."""
        evidence = np.array([t.log_evidence for t in self.tracks])
        share = np.exp(evidence - logsumexp(evidence))
        joint = np.einsum("j,jck->ck", share, np.array([t.joint_posterior for t in self.tracks]))
        joint /= joint.sum()
        return joint, self.tracks[int(np.argmax(evidence))]

    def log_class_posterior(self) -> np.ndarray:
        """``log`` of the mixture's class posterior ``(C,)`` (``mixed_log_class_posterior`` by evidence)."""
        return mixed_log_class_posterior(self.tracks, np.array([t.log_evidence for t in self.tracks]))


def mixed_log_class_posterior(tracks: tuple[TrackRecord, ...], log_weights: np.ndarray) -> np.ndarray:
    """``log`` of the tracks' class posteriors mixed with weights ``softmax(log_weights)``, ``(C,)``, summed in
    log space: with a track per primitive the classes' evidence differs by hundreds of nats, which
    probabilities would round to 0 and 1."""
    log_share = log_weights - logsumexp(log_weights)
    with np.errstate(divide="ignore"):
        log_class = np.log(np.array([t.joint_posterior.sum(axis=1) for t in tracks]))
    return logsumexp(log_share[:, None] + log_class, axis=0)


def with_known_base(qpos: np.ndarray, known_pose: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """A configuration ``(57,)`` with its base replaced by ``known_pose`` when there is one."""
    if known_pose is None:
        return qpos
    return np.concatenate([known_pose[0], known_pose[1], qpos[7:]])


def causal_estimate(records: list[FrameRecord], classes: np.ndarray, timing: dict, *, temperature: float = 1.0,
                    floor: float = 0.0, unknown_bias: float = 0.0) -> Estimate:
    """The engine's causal estimate from its frame records (module docstring); its class posterior is the
    mixture's calibrated by ``temperature``, ``floor`` and the background class's ``unknown_bias``
    (``confidence.calibrated``), the raw one kept as ``raw_log_posterior``."""
    first = next((i for i, r in enumerate(records) if r.tracks), None)
    if first is None:
        raise EngineError("no frame had any flow: nothing to estimate")
    rows = []
    for record in records[first:]:
        joint, lead = record.decision()
        rows.append((lead.qpos, record.log_class_posterior(), joint, lead.position, lead.quat, len(record.tracks),
                     lead.origin, record.ms))
    rows = [(with_known_base(rows[0][0], r.known_pose),) + rows[0][1:7] + (0.0,) for r in records[:first]] + rows
    qpos, log_post, joint, fpos, fquat, n_tracks, leader, ms = (np.array(x) for x in zip(*rows))
    post = calibrated(log_post, temperature, floor, class_bias(classes, unknown_bias))
    return Estimate(classes, qpos, post, joint, fpos, fquat, n_tracks, leader, ms, timing, raw_log_posterior=log_post)


def track_path(records: list[FrameRecord], track_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One track's configurations ``(T, 57)`` and filter poses ``(T, 3)``, ``(T, 4)`` over every frame, frames
    before its first record padded as the module docstring says."""
    mine = [next((t for t in r.tracks if t.track_id == track_id), None) for r in records]
    start = next(i for i, t in enumerate(mine) if t is not None)
    qpos = [with_known_base(mine[start].qpos, r.known_pose) for r in records[:start]]
    qpos += [t.qpos for t in mine[start:]]
    pos = [mine[start].position] * start + [t.position for t in mine[start:]]
    quat = [mine[start].quat] * start + [t.quat for t in mine[start:]]
    return np.array(qpos), np.array(pos), np.array(quat)


def offline_estimate(records: list[FrameRecord], causal: Estimate, smoothing_frames: float,
                     stream: bool) -> Estimate:
    """The hindsight estimate (module docstring): the final leader's whole path smoothed over
    ``smoothing_frames``; the final posteriors at every frame unless ``stream``."""
    _, lead = records[-1].decision()
    qpos, pos, quat = track_path(records, lead.track_id)
    T = len(records)
    post, joint = causal.class_posterior, causal.joint_posterior
    if not stream:
        post, joint = np.repeat(post[-1:], T, axis=0), np.repeat(joint[-1:], T, axis=0)
    return replace(causal, qpos=smooth_trajectory(qpos, smoothing_frames), class_posterior=post,
                   joint_posterior=joint, filter_pos=pos, filter_quat=quat, leader=np.full(T, lead.origin))
