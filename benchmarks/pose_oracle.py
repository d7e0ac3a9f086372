"""What would the causal tracker's pose be if it knew the posture, or the depth it starts at? An oracle, for
diagnosis only: it hands the tracker ground truth the engine may never see.

    MUJOCO_GL=egl python benchmarks/pose_oracle.py [--scenario scenarios/default.yaml] [--seed S ...]
        [--amount 0.0 0.4] [--limit N] [--jobs 2] [--variants engine reference posture ...]

Every run is tracked once per variant (the causal estimate, ``full``; the backward pass off), with the same random
stream:
- ``engine``: the engine as it is;
- ``reference``: without re-injection (``reinject_every`` 0), as every oracle variant runs: a newcomer's evidence
  would be the database's;
- ``posture``: each frame every particle weighed at the true posture and motion (angles, rates, the base's
  velocities) known up to the mirror, the mixture half and half of the true features and their mirror image
  (``features.mirror_features``), so that the twin keeps its mirrored body and only perspective tells it; each
  track's evidence the frame's likelihood under its cloud at that posture instead of recognition's, so the tracks
  are chosen by it too;
- ``posture0.1``: the same with every true angle off by a fixed offset of std 0.1 rad, one per angle and run
  (``depth_profile.true_features``), and every angle with the std 0.1 rad;
- ``angles``: as ``posture``, but only the angles true (exact), the rates and the base's velocities the track's
  belief's (its primitive's states under the belief, moment-matched in joint space: ``depth_profile.part_features``);
  ``angles0.1``: the angles off by a fixed 0.1 rad with the std 0.1 rad; ``angles+rates``: the rates true too;
- ``depth``: the reference with every spawned particle moved along its ray to the true depth;
- ``posture+depth``, ``angles+depth``: both.

The oracles replace ``ParticleTracks.start`` and ``log_likelihoods`` and ``Tracker._recognise`` in this process's
workers only. Prints per condition and variant the mean heading error over runs (and its median, the share within
20 deg, the error up to the twin) and the baselink error (over the clip, its first and last 30%, and the estimated
depth at the end against the truth's), then the mean heading error per class. ``docs/engine.md``, "The tracker with
the posture known, an oracle".
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np

import dev_runs

# name: (the posture oracle's angle offset and std in rad, or None for none; the spawn at the true depth; the
# feature groups taken from the truth into each track's belief (``depth_profile.PARTS``), or None for every feature)
VARIANTS = {"engine": (None, False, None), "reference": (None, False, None), "posture": (0.0, False, None),
            "posture0.1": (0.1, False, None), "angles": (0.0, False, ("true-angles",)),
            "angles0.1": (0.1, False, ("true-angles",)), "angles+rates": (0.0, False, ("true-angles", "true-rates")),
            "depth": (None, True, None), "posture+depth": (0.0, True, None),
            "angles+depth": (0.0, True, ("true-angles",))}
# What the oracles hand the tracker in this worker: per frame the two-state point distributions of the true
# posture and its mirror image ("posture"), or the true features, the groups of them put into each track's belief
# and the angles' std ("parts"); and the true depths ("depth"). Empty: the engine's own.
_ORACLE: dict = {}


def _posture_known() -> bool:
    """Whether the oracle hands the weighing a posture (the same for every track, or true features in each
    track's belief)."""
    return "posture" in _ORACLE or "parts" in _ORACLE


def _install() -> None:
    """Replace the tracker's spawn, weighing and evidence by the oracles' (``_ORACLE``) in this process; the
    originals run whenever the oracle is empty."""
    from scipy.special import logsumexp

    from depth_profile import PARTS, belief_rows, mirrored_points, part_features
    from harness.engine import pose_source, tracker
    from harness.engine.features import ANGLES
    from harness.engine.transform import PointDistributions

    def _part_pair(source, track, t):
        """The track's belief's blob in joint space with the oracle's feature groups true (the angles with the
        oracle's std), and its mirror image."""
        model, c = source.scorer.model, track.primitive
        features, names, std = _ORACLE["parts"]
        groups = tuple(g for name in names for g in PARTS[name])
        mean, var = part_features(model, belief_rows(track.recognizer, c)[c], c, features[t], groups)
        if "true-angles" in names:
            var[:, ANGLES] = std**2
        truth, twin = mirrored_points(model, mean, var)
        return truth[0], twin[0]

    if getattr(pose_source, "_oracle_installed", False):
        return
    start, weigh, recognise = (pose_source.ParticleTracks.start, pose_source.ParticleTracks.log_likelihoods,
                               tracker.Tracker._recognise)

    def oracle_start(self, frame):
        tracks = start(self, frame)
        if "depth" in _ORACLE:
            for t in tracks:
                p = t.cloud.positions
                t.cloud.positions = p * (_ORACLE["depth"][frame.index] / p[:, 2])[:, None]
        return tracks

    def oracle_weigh(self, frame, tracks):
        if not _posture_known():
            return weigh(self, frame, tracks)
        pos = np.concatenate([t.cloud.positions for t in tracks])
        quat = np.concatenate([t.cloud.quats for t in tracks])
        n = len(pos)
        sizes = [len(t.cloud) for t in tracks]
        if "parts" in _ORACLE:          # each track's own pair: some true features in its belief's blob
            dists = PointDistributions.concatenate([d for t in tracks for d in _part_pair(self, t, frame.index)])
            first = np.repeat(2 * np.arange(len(tracks)), sizes)
        else:
            dists, first = _ORACLE["posture"][frame.index], np.zeros(n, dtype=int)
        both = self.scorer.pose_log_likelihood(frame, np.concatenate([quat, quat]), np.concatenate([pos, pos]), dists,
                                               np.concatenate([first, first + 1]),
                                               n_eff=self.scorer.config.n_eff_filter)
        ll = np.logaddexp(both[:n], both[n:]) - np.log(2.0)
        out, at = [], 0
        for t in tracks:
            own = ll[at:at + len(t.cloud)]
            at += len(t.cloud)
            prior = t.cloud.log_weights - logsumexp(t.cloud.log_weights)
            t.oracle_evidence = getattr(t, "oracle_evidence", 0.0) + float(logsumexp(prior + own))
            out.append(own)
        return out

    def oracle_recognise(self, frame):
        recognise(self, frame)
        if _posture_known():
            for t in self.tracks:
                t.log_evidence = getattr(t, "oracle_evidence", 0.0)

    pose_source.ParticleTracks.start = oracle_start
    pose_source.ParticleTracks.log_likelihoods = oracle_weigh
    tracker.Tracker._recognise = oracle_recognise
    pose_source._oracle_installed = True


def _one(job, variants: tuple[str, ...]) -> dict:
    run, overrides = job
    _install()
    from depth_profile import mirrored_points, true_features
    from harness.engine.transform import PointDistributions
    from harness.evaluation import metrics, pipeline

    inputs = pipeline.run_inputs(run)
    truth = inputs.truth
    out = {"key": run.key, "condition": run.condition_label, "class": run.test_class}
    for name in variants:
        posture, depth, parts = VARIANTS[name]
        settings = {"backward_pass": False} | ({} if name == "engine" else {"reinject_every": 0})
        tracker = dev_runs.tracker_for(inputs, overrides | settings)
        _ORACLE.clear()
        if depth:
            _ORACLE["depth"] = truth.base_pos_cam[:, 2]
        if parts is not None:
            _ORACLE["parts"] = (true_features(run, inputs, posture), parts, posture)
        elif posture is not None:
            pairs = zip(*mirrored_points(tracker.model, true_features(run, inputs, posture), posture))
            _ORACLE["posture"] = [PointDistributions.concatenate([a, b]) for a, b in pairs]
        try:
            qpos = tracker.run(inputs.obs, rng=np.random.default_rng(run.config.seed)).qpos
        finally:
            _ORACLE.clear()
        err = np.linalg.norm(qpos[:, :3] - truth.base_pos_cam, axis=1)
        T = len(err)
        quats = (qpos[:, 3:7], truth.base_quat_cam, truth.camera_rot)
        out[name] = {
            "heading": metrics.heading_tilt_errors(*quats)["heading_err_deg"],
            "twin": metrics.heading_twin_error(*quats)["heading_err_twin_deg"],
            "baselink": float(err.mean()), "first": float(err[:max(1, int(0.3 * T))].mean()),
            "last": float(err[int(0.7 * T):].mean()),
            "depth_end": float(np.median(qpos[int(0.7 * T):, 2] / truth.base_pos_cam[int(0.7 * T):, 2]))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(partial(_one, variants=tuple(args.variants)), dev_runs.selected(args), args)
    print("mean over runs: heading error (deg; median, share within 20 deg, up to the twin) and baselink error (m; "
          "over the clip, its first and last 30%), and the estimated depth at the end against the truth's (median, "
          "10-90%)")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        print(f"{cond} ({len(sub)} runs)")
        for name in args.variants:
            v = {k: np.array([r[name][k] for r in sub]) for k in sub[0][name]}
            print(f"  {name:14s} heading {v['heading'].mean():5.1f} ({np.median(v['heading']):5.1f}, "
                  f"{np.mean(v['heading'] <= 20.0):.2f}, twin {v['twin'].mean():5.1f})   baselink "
                  f"{v['baselink'].mean():.2f} ({v['first'].mean():.2f}, {v['last'].mean():.2f})   depth at the end "
                  f"{np.median(v['depth_end']):.2f} ({np.percentile(v['depth_end'], 10):.2f}-"
                  f"{np.percentile(v['depth_end'], 90):.2f})")
    classes = sorted({r["class"] for r in rows})
    print("\nmean heading error per class (deg), all conditions")
    print(f"  {'class':13s} " + " ".join(f"{n:>14s}" for n in args.variants))
    for c in classes:
        sub = [r for r in rows if r["class"] == c]
        print(f"  {c:13s} " + " ".join(f"{np.mean([r[n]['heading'] for r in sub]):14.1f}" for n in args.variants))
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
