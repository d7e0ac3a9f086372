"""The offline backward pass: the clip tracked again from its end, where the causal pass's poses have settled.

The causal pass starts its tracks from one frame's guess; its poses settle within about 40% of a clip
(``docs/engine.md``, heading over time), and a class whose tracks were in the wrong pose early may have been
pruned before its pose settled. Offline, the whole clip is known. The backward pass plays the clip backwards
(``reverse``: flows and database in reversed time) and starts one set of tracks per primitive at the poses
the causal pass ended with:

- a primitive still tracked at the end starts from its own best final cloud (its live track with the most
  evidence), the others from the causal leader's final cloud (the body's settled pose, whatever the primitive);
- each start also spawns its twin (``track.twin``), since a settled pose may still be the twin's.

With ``offline.backward_live_only``, only the primitives with a live track start (about half the pass's time).

Each backward track believes only its primitive (late commitment, as in the causal pass), is moved, weighed,
recognised, recovered, pruned and merged by the causal loop's own stages, with the reversed model. At the end
of the backward pass (the clip's first frame) every track has the evidence of the whole clip along its own
path. The offline estimate is that pass's: the class posterior of its final frame (the evidence-weighted
mixture over its tracks) at every frame, and the whole path of its track with the most evidence, smoothed,
in forward time.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from harness.engine.confidence import calibrated, class_bias
from harness.engine.config import BeliefSettings
from harness.engine.estimate import Estimate
from harness.engine.particle_filter import ParticleCloud
from harness.engine.pose_source import ParticleTracks
from harness.engine.records import FrameRecord
from harness.engine.track import Track, twin


class SettledStarts(ParticleTracks):
    """The backward pass's pose source: the causal pass's final clouds, one set per primitive (module
    docstring), instead of a first frame's search; every other stage as the causal ``ParticleTracks``. Unlike the
    causal spawn, the starts are weighed by the first frame (the causal pass's last, whose weights the clouds
    carry): unweighed, the smoothed heading was 4.3 +- 2.8 deg worse on 240 development runs (docs/engine.md; measured
    while the starts that shared the leader's cloud were weighed once per holder, fixed 2026-12-06)."""

    def __init__(self, scorer, rng, starts: list[tuple[int, str, ParticleCloud]], **settings):
        super().__init__(scorer, rng, **settings)
        self.starts = starts

    def start(self, frame) -> list[Track]:
        tracks = []
        for primitive, origin, cloud in self.starts:
            variants = [(origin, cloud.quats.copy())]
            if self.spawn_settings.twin:
                variants.append((origin + "~twin", twin(cloud.quats, frame.gravity)))
            for name, quats in variants:
                # Every start its own copy: the primitives without a live track start from the same leader's
                # cloud, and a cloud that several tracks held was weighed once per holder, by each one's primitive.
                c = ParticleCloud(cloud.positions.copy(), quats, cloud.log_weights.copy())
                belief = self.new_belief().restrict([primitive])
                prefix = f"{self.scorer.model.db.classes_[primitive]}/"
                tracks.append(Track(self._spawned, prefix + name, belief, c, primitive=primitive, memory=self.memory))
                self._spawned += 1
        return tracks


def settled_starts(final_tracks: list[Track], n_classes: int, live_only: bool = False
                   ) -> list[tuple[int, str, ParticleCloud]]:
    """One start per primitive (``(primitive, origin, cloud)``): the cloud of its live final track with the most
    evidence, or the leader's cloud for a primitive without a live track (module docstring); with ``live_only``,
    only the primitives with a live track."""
    ranked = sorted(final_tracks, key=lambda t: -t.log_evidence)
    starts = []
    for c in range(n_classes):
        own = next((t for t in ranked if t.primitive == c), None)
        if own is not None:
            starts.append((c, "end:" + own.origin.split("/")[-1], own.cloud))
        elif not live_only:
            starts.append((c, "end:leader", ranked[0].cloud))
    return starts


def both_passes(offline: Estimate, forward: FrameRecord, backward: FrameRecord, belief: BeliefSettings) -> Estimate:
    """The offline estimate with its class posterior decided by both passes' final tracks (``offline.both_passes``):
    a primitive's evidence is the best path either pass found for it (each track's evidence is the whole
    clip's, along its own path), mixed as ``FrameRecord.log_class_posterior`` mixes one pass's tracks."""
    both = FrameRecord(forward.index, forward.tracks + backward.tracks, None, 0.0)
    log_post = both.log_class_posterior()
    T = len(offline.qpos)
    post = calibrated(log_post[None], belief.posterior_temperature, belief.posterior_floor,
                      class_bias(offline.classes, belief.unknown_bias))
    return replace(offline, class_posterior=np.repeat(post, T, axis=0),
                   raw_log_posterior=np.repeat(log_post[None], T, axis=0))


def in_forward_time(rev: Estimate) -> Estimate:
    """An estimate of the reversed clip with every per-frame array put back in forward time."""
    flip = {name: getattr(rev, name)[::-1].copy() for name in ("qpos", "class_posterior", "joint_posterior",
                                                                "filter_pos", "filter_quat", "n_tracks", "leader",
                                                                "ms_per_frame", "raw_log_posterior")
            if getattr(rev, name) is not None}
    return replace(rev, offline=None, **flip)
