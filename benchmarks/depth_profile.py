"""Which depth does the particles' weighing prefer, when the other degrees of freedom may move?

    MUJOCO_GL=egl python benchmarks/depth_profile.py [--scenario scenarios/default.yaml] [--seed S]
        [--amount 0.0 0.4] [--limit N] [--jobs 2] [--position-scale 1.0] [--top-state]

For every run, the true base path is scaled in depth about the camera centre by each of ``SCALES`` (the body
stays where the flows are, smaller or larger), and at each scale the path is also moved by every combination of
a constant offset along the camera's y axis (``OFFSETS_M``) and a constant pitch about the camera's x axis
(``PITCHES_DEG``): what a track can change to make a nearer or farther body fit. Every frame's flows are
scored as the particles are weighed (``Scorer.pose_log_likelihood``, the flows' joint likelihood tempered by
``n_eff_filter``, and a known floor's term if the scenario gives the camera's height) under the true primitive's moment-matched belief along the true path (the recursion of a track
that believes only it). Summed over the clip, each scale's best score over the offsets and pitches is its
*profile*; the unmoved path's score is its *exact* value. Prints per run and per condition where each peaks and
each scale's median score against the true depth's (tempered nats over the clip).

``--position-scale K`` multiplies the weighing's position covariances by ``K`` (the depth's calibration against
the covariances' width); ``--top-state`` weighs under the belief's most probable state alone instead of the
moment-matched blob of its states.

``--posture true-angles|true-motion|true-rates|true-base`` weighs under the belief's blob as one Gaussian over the
features (the states' moments in joint space) with the true angles, the true rates and base velocities, the rates
alone or the base velocities alone put in exactly (no variance): which of the posture's parts carries the depth.

``--posture true|recovered`` weighs at one posture per frame instead of the belief's states: the true angles and
rates (``--posture-noise S``: each angle off by a Gaussian offset of std ``S`` rad, one per angle and run, seeded),
or the angles the engine recovers handed the true base pose scaled in depth by ``--recovered-at K`` (the
``gt_base`` run's; K = 1: the true base) with their own rates (backward differences); the true base velocities;
every angle with the std ``--posture-std S`` rad (0: the surface patch alone). How well the posture is known sets
how sharply the flows tell depth (``docs/engine.md``, "The width is the posture's uncertainty").
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import zlib
from functools import partial

import numpy as np

import dev_runs
from harness.engine.features import ANGLE_RATES, ANGLES, BASE_ANGULAR, BASE_LINEAR, motion_features

SCALES = np.array([0.8, 0.9, 1.0, 1.1, 1.2, 1.35, 1.5])
OFFSETS_M = np.linspace(-0.4, 0.4, 17)
PITCHES_DEG = np.arange(-20.0, 21.0, 5.0)
TRUE = int(np.flatnonzero(SCALES == 1.0)[0])
# The feature groups ``--posture true-angles`` ... take from the truth (``part_features``).
PARTS = {"true-angles": (ANGLES,), "true-motion": (ANGLE_RATES, BASE_LINEAR, BASE_ANGULAR),
         "true-rates": (ANGLE_RATES,), "true-base": (BASE_LINEAR, BASE_ANGULAR)}


def _one(job, position_scale: float = 1.0, top_state: bool = False, posture: str = "belief", posture_std: float = 0.0,
         posture_noise: float = 0.0, recovered_at: float = 1.0) -> dict:
    run, overrides = job
    from harness import geometry
    from harness.engine.frame import observation_frames

    along = dev_runs.true_primitive(run, overrides)
    inputs, tracker, scorer, c, rec = along.inputs, along.tracker, along.scorer, along.primitive, along.recognizer
    obs, truth, model, cfg = inputs.obs, inputs.truth, tracker.model, tracker.config
    pos, quat = truth.base_pos_cam, truth.base_quat_cam
    by_belief = posture == "belief" or posture in PARTS      # weighed under the belief, which then runs
    postures = None if by_belief else _postures(run, inputs, tracker, posture, posture_std, posture_noise,
                                                recovered_at)
    true = true_features(run, inputs) if posture in PARTS else None
    S, D, P = len(SCALES), len(OFFSETS_M), len(PITCHES_DEG)
    half = np.deg2rad(PITCHES_DEG) / 2
    pitch = np.stack([np.cos(half), np.sin(half), np.zeros(P), np.zeros(P)], axis=1)      # about camera x
    pitches = np.broadcast_to(pitch[None, None], (S, D, P, 4)).reshape(-1, 4)
    offsets = np.zeros((S, D, P, 3))
    offsets[..., 1] = OFFSETS_M[None, :, None]
    total, started = np.zeros((S, D, P)), False
    for frame in observation_frames(obs, cfg):
        t = frame.index
        if not (started or frame.has_flows):
            continue
        started = True
        if by_belief:
            rec.predict()
        if frame.has_flows:
            if posture in PARTS:
                dists = posture_points(model, *part_features(model, belief_rows(rec, c)[c], c, true[t],
                                                             PARTS[posture]))[0]
            else:
                dists = _belief_blob(model, rec, c, top_state) if postures is None else postures[t]
            dists = dataclasses.replace(dists, pos_cov=dists.pos_cov * position_scale)
            p = (SCALES[:, None, None, None] * pos[t] + offsets).reshape(-1, 3)
            q = geometry.multiply(pitches, np.broadcast_to(quat[t], (S * D * P, 4)))
            total += scorer.pose_log_likelihood(frame, q, p, dists, n_eff=cfg.n_eff_filter).reshape(S, D, P)
        if by_belief:
            scorer.recognise(frame, [rec], pos[t][None], quat[t][None])
    flat = total.reshape(S, -1)
    best = np.unravel_index(flat[int(flat.max(axis=1).argmax())].argmax(), (D, P))
    return {"key": run.key, "condition": run.condition_label, "class": run.test_class,
            "profile": flat.max(axis=1), "exact": total[:, D // 2, P // 2],
            "offset_m": float(OFFSETS_M[best[0]]), "pitch_deg": float(PITCHES_DEG[best[1]])}


def belief_rows(rec, c: int) -> np.ndarray:
    """``(C, S)`` the belief ``rec``'s posterior over primitive ``c``'s active states, zero elsewhere."""
    rows = np.where(rec.active(), rec.state_posterior, 0.0)
    rows[np.arange(len(rows)) != c] = 0.0
    return rows


def _belief_blob(model, rec, c: int, top_state: bool):
    """The moment-matched blob of primitive ``c``'s active states under the belief ``rec`` (or its most probable
    state alone, ``top_state``)."""
    rows = belief_rows(rec, c)
    if top_state:
        rows = (np.arange(rows.size) == rows.argmax()).astype(float).reshape(rows.shape)
    return model.dists.mixtures(rows.reshape(1, -1) / rows.sum())


def _postures(run, inputs, tracker, posture: str, std: float, noise: float, recovered_at: float) -> list:
    """Per frame the model points' distributions at one posture (``--posture``, module docstring)."""
    if posture == "recovered":
        truth = inputs.truth
        features = recovered_features(inputs, tracker, recovered_at * truth.base_pos_cam, truth.base_quat_cam,
                                      true_features(run, inputs))
    else:
        features = true_features(run, inputs, noise)
    return posture_points(tracker.model, features, std)


def recovered_features(inputs, tracker, positions: np.ndarray, quats: np.ndarray, features: np.ndarray) -> np.ndarray:
    """``features`` ``(T, 106)`` with the angles the engine recovers when handed the base path ``positions``,
    ``quats`` (camera frame; the ``gt_base`` run's) and their rates (backward differences) in place of theirs."""
    angles = tracker.run(inputs.obs, base_pose=(positions, quats)).qpos[:, 7:]
    out = np.array(features, dtype=float)
    out[:, ANGLES] = angles
    out[:, ANGLE_RATES] = np.diff(angles, axis=0, prepend=angles[:1]) * inputs.obs.fps
    return out


def true_features(run, inputs, noise: float = 0.0) -> np.ndarray:
    """``(T, 106)`` the true motion's features (``features.motion_features`` of the performed motion), every angle
    off by a Gaussian offset of std ``noise`` rad: one offset per angle for the run (a posture that is off, not one
    that jitters), seeded by the run's seed and key."""
    features = motion_features(inputs.motion)
    rng = np.random.default_rng([run.config.seed, zlib.crc32(run.key.encode())])
    features[:, ANGLES] += rng.normal(0.0, noise, features[:, ANGLES].shape[1])
    return features


def posture_points(model, features: np.ndarray, angle_std: float | np.ndarray) -> list:
    """Per frame of ``features`` ``(T, 106)`` the model points' distributions at that one posture: every angle
    with the std ``angle_std`` rad (0: the surface patch alone), the rates and the base's velocities exact; or
    with ``angle_std`` the features' variances ``(T, 106)``."""
    from harness.engine.transform import JointGaussians, state_point_distributions

    if np.ndim(angle_std) == 0:
        var = np.zeros(features.shape)
        var[:, ANGLES] = angle_std**2
    else:
        var = np.asarray(angle_std, dtype=float)
    return [state_point_distributions(model.body, JointGaussians.from_features(f[None], v[None]), model.points,
                                      model.spread) for f, v in zip(features, var)]


def mirrored_points(model, features: np.ndarray, angle_std: float | np.ndarray) -> tuple[list, list]:
    """``posture_points`` at ``features`` and at their mirror image (``features.mirror_features``; a variance
    or std ``features.mirror_variances``): the body and its reflected twin."""
    from harness.engine.features import mirror_features, mirror_variances

    mirrored_std = angle_std if np.ndim(angle_std) == 0 else mirror_variances(angle_std)
    return (posture_points(model, features, angle_std),
            posture_points(model, mirror_features(features), mirrored_std))


def part_features(model, weights: np.ndarray, c: int, true: np.ndarray,
                  groups: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``(1, 106)`` means and variances: primitive ``c``'s states under ``weights`` (its states' posterior)
    moment-matched in joint space, with the feature ``groups`` (index arrays) set to the ``true`` features and no
    variance."""
    gamma = weights / weights.sum()
    means, covars = model.db.means_[c], model.db.covars_[c]
    mean = gamma @ means
    var = gamma @ (covars + (means - mean) ** 2)
    for group in groups:
        mean[group], var[group] = true[group], 0.0
    return mean[None], var[None]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.add_argument("--position-scale", type=float, default=1.0, help="the weighing's position covariances x this")
    ap.add_argument("--top-state", action="store_true", help="the belief's most probable state instead of its blob")
    ap.add_argument("--posture", choices=["belief", "true", "recovered", *PARTS], default="belief",
                    help="weigh at one posture per frame (module docstring)")
    ap.add_argument("--posture-std", type=float, default=0.0, help="rad: every angle's std at that posture")
    ap.add_argument("--posture-noise", type=float, default=0.0, help="rad: std of a fixed offset on each true angle")
    ap.add_argument("--recovered-at", type=float, default=1.0, help="the recovered posture's base at this x the "
                    "true depth")
    args = ap.parse_args()
    runs = dev_runs.selected(args)
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(partial(_one, position_scale=args.position_scale, top_state=args.top_state,
                                      posture=args.posture, posture_std=args.posture_std,
                                      posture_noise=args.posture_noise, recovered_at=args.recovered_at), runs, args)
    print(f"{'run':28s} {'condition':24s} exact  profile  (peaks; then the profile per scale against the true depth,"
          f" and the best offset and pitch)")
    for r in rows:
        print(f"{r['key']:28s} {r['condition']:24s} {SCALES[r['exact'].argmax()]:5.2f} {SCALES[r['profile'].argmax()]:8.2f}  "
              + " ".join(f"{v - r['profile'][TRUE]:7.1f}" for v in r["profile"])
              + f"  {r['offset_m']:+.2f} m {r['pitch_deg']:+.0f} deg")
    print(f"\nscales: {', '.join(f'{s:g}' for s in SCALES)}")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        for name in ("exact", "profile"):
            peaks = np.array([SCALES[r[name].argmax()] for r in sub])
            rel = np.median([r[name] - r[name][TRUE] for r in sub], axis=0)
            print(f"{cond} {name:8s}: peak median {np.median(peaks):.2f}, at the true depth in {np.sum(peaks == 1.0)} "
                  f"of {len(sub)}, farther in {np.sum(peaks > 1.0)}; median against the true depth: "
                  + " ".join(f"{v:.1f}" for v in rel))
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
