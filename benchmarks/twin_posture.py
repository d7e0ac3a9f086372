"""How sharply do the flows tell the true pose from its exact twin, and how does that depend on the posture?

    MUJOCO_GL=egl python benchmarks/twin_posture.py [--scenario scenarios/default.yaml] [--seed S]
        [--amount 0.0 0.4] [--limit N] [--jobs 2] [--set KEY=VALUE ...] [--offsets 0.1 0.2] [--samples K]
        [--recovered STD] [--plot PNG]

For every run, every frame's flows are scored as the particles are weighed (``Scorer.pose_log_likelihood``, the
flows' joint likelihood tempered by ``n_eff_filter``) at the true base pose and at its exact twin
(``track.twin``: the depth reflected through the pelvis and the body mirrored left to right; the same position),
each at a posture:
- ``blob``: the true primitive's moment-matched belief along the true path (the recursion of a track that
  believes only it), as the engine weighs; the twin under the same belief mirrored (each state's posterior moved
  to its mirror-image chain, ``database.mirror_chains``);
- ``true``: the true angles, their rates and the base's velocities, the surface patch alone; the twin at the
  mirror image of that posture (``features.mirror_features``), which is exactly the reflected body;
- ``off<S>``: the true angles each off by a fixed offset of std ``S`` rad (one per angle and run, seeded, as
  ``depth_profile.py --posture-noise``) and every angle with the std ``S``; the twin at its mirror image;
- ``sampled<K>`` (``--samples K``): ``K`` postures drawn from the belief each frame (a state by its posterior,
  then every feature from that state's Gaussian; the twin at each draw's mirror image), a pose's score the log
  mean over the draws of the frame's tempered likelihood at one posture: the flows share a posture, as one body's
  do, where the blob lets each flow take its own;
- ``recovered<S>`` (``--recovered S``): each path at the posture the engine recovers when handed that path
  (the ``gt_base`` run along the true positions with the truth's or the twin's orientations), every angle with
  the std ``S`` rad, the rates by backward differences of the recovered angles, the base's velocities true
  (the twin's mirrored);
- with ``--parts``, which of the features the ``true`` posture knows carry the margin: the belief's blob as one
  Gaussian over the features (``feature_blob``: the states' moments in joint space, carried to the points as one
  state; the engine moment-matches at the points instead) with one group of features replaced by the truth's
  (exact, no variance): ``true-angles``, ``true-motion`` (the rates and the base's velocities), ``true-rates``,
  ``true-base`` (the base's linear and angular velocities; ``depth_profile.PARTS``); the twin at the mirror image
  of the same features.
- with ``--read-motion STD``, ``read-motion``: the same feature blob with its motion (the rates and the base's
  velocities) read from the flows' velocities at each path (``read_motion``: the motion's Gaussian posterior
  given the flows assigned to the model points by position, a linear fit at the blob's mean angles with each
  point's velocity known to ``STD`` px/s), the truth's at the true pose and the twin's at the twin pose; and
  how far the read motion is from the truth's beside the blob's (rms, rad/s and m/s).

Summed over the clip, the truth's score minus the twin's is the twin's *margin* (tempered nats): printed per
condition and class as the median over runs and the share of runs in which the truth scores higher. Also per
condition: how far the belief's posture is from the true one along the true path (the true angles minus the
belief's mean angles, rms over the angles the performance moves), beside the blob's own spread, and split into
the part that is constant over the clip (the performer's style: its mean) and the part that varies; with
``--recovered``, the same for the angles recovery finds handed the true base path. The exact
twin is held at the true position; a track at the twin heading may also move and pitch to fit better, so these
margins bound what the weighing can tell, they are not what the tracks see. ``docs/engine.md``, "The twin is told
as sharply as the posture is known".
"""

from __future__ import annotations

import argparse
import time
import zlib
from collections import defaultdict
from functools import partial
from pathlib import Path

import numpy as np

import dev_runs
from depth_profile import (PARTS, belief_rows, mirrored_points, part_features, posture_points, recovered_features,
                           true_features)
from harness.engine.features import ANGLES


def _one(job, offsets: tuple[float, ...], recovered: float | None, samples: int = 0, parts: bool = False,
         read_std: float | None = None) -> dict:
    run, overrides = job
    from harness.engine.features import mirror_features
    from harness.engine.frame import observation_frames
    from harness.engine.track import twin

    along = dev_runs.true_primitive(run, overrides)
    inputs, tracker, scorer, c, rec = along.inputs, along.tracker, along.scorer, along.primitive, along.recognizer
    obs, truth, model, cfg = inputs.obs, inputs.truth, tracker.model, tracker.config
    pos, quat = truth.base_pos_cam, truth.base_quat_cam
    poses = (quat, twin(quat))
    true = true_features(run, inputs)
    postures = {}
    for name, noise in [("true", 0.0)] + [(f"off{s:g}", s) for s in offsets]:
        features = true if noise == 0.0 else true_features(run, inputs, noise)
        postures[name] = mirrored_points(model, features, noise)
    recovered_angles = None
    if recovered is not None:       # the twin's base velocities are the true ones mirrored
        along_paths = [recovered_features(inputs, tracker, pos, q, f)
                       for q, f in zip(poses, (true, mirror_features(true)))]
        postures[f"recovered{recovered:g}"] = tuple(posture_points(model, f, recovered) for f in along_paths)
        recovered_angles = along_paths[0][:, ANGLES]
    half = model.db.means_.shape[1] // 2        # a both-handed primitive's chain and its mirror image
    sampled = f"sampled{samples}"
    part_modes = (["feature_blob", *PARTS] if parts else []) + (["read-motion"] if read_std else [])
    motion_errors = defaultdict(list)
    margin = dict.fromkeys(["blob", *postures] + ([sampled] if samples else []) + part_modes, 0.0)
    rng = np.random.default_rng([run.config.seed, zlib.crc32(run.key.encode()), 1])
    angle_means, angle_vars = model.db.means_[c][:, ANGLES], model.db.covars_[c][:, ANGLES]
    errors, blob_vars, recovery_errors = [], [], []
    started = False
    for frame in observation_frames(obs, cfg):
        t = frame.index
        if not (started or frame.has_flows):
            continue
        started = True
        rec.predict()
        if frame.has_flows:
            rows = belief_rows(rec, c)
            gamma = rows[c] / rows[c].sum()
            mean = gamma @ angle_means
            errors.append(truth.qpos[t, 7:] - mean)
            if recovered_angles is not None:
                recovery_errors.append(truth.qpos[t, 7:] - recovered_angles[t])
            blob_vars.append(gamma @ (angle_vars + (angle_means - mean) ** 2))
            mirrored = np.concatenate([rows[:, half:], rows[:, :half]], axis=1)
            dists = {"blob": (model.dists.mixtures(rows.reshape(1, -1) / rows.sum()),
                              model.dists.mixtures(mirrored.reshape(1, -1) / mirrored.sum()))}
            dists |= {name: (a[t], b[t]) for name, (a, b) in postures.items()}
            if parts:
                dists |= _part_blobs(model, rows[c], c, true[t])
            if read_std:
                dists["read-motion"] = _read_motion_blobs(scorer, frame, model, rows[c], c, poses, pos[t], t,
                                                          read_std, true[t], motion_errors)
            if samples:
                margin[sampled] += _sampled_margin(scorer, frame, model, rows.reshape(-1), samples, rng,
                                                   [(q[t], pos[t]) for q in poses], cfg.n_eff_filter)
            for name, pair in dists.items():
                score = [scorer.pose_log_likelihood(frame, q[t][None], pos[t][None], d, n_eff=cfg.n_eff_filter)[0]
                         for q, d in zip(poses, pair)]
                margin[name] += float(score[0] - score[1])
        scorer.recognise(frame, [rec], pos[t][None], quat[t][None])
    moving = np.ptp(truth.qpos[:, 7:], axis=0) > 1e-3       # the angles the performance moves
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    posture = {"blob_std": rms(np.sqrt(np.array(blob_vars)[:, moving]))}
    for name, err in (("", errors), ("recovered_", recovery_errors)):
        if len(err):
            err = np.array(err)[:, moving]
            offset = err.mean(axis=0)
            posture |= {name + "error": rms(err), name + "offset": rms(offset), name + "varying": rms(err - offset)}
    for name, err in motion_errors.items():
        err = np.array(err)
        posture[name] = rms(err[:, moving] if name.endswith("rates") else err)
    return {"key": run.key, "condition": run.condition_label, "class": run.test_class, "margin": margin,
            "posture": posture}


def _part_blobs(model, weights: np.ndarray, c: int, true: np.ndarray) -> dict:
    """``--parts``' pairs (truth, twin) of point distributions: primitive ``c``'s states under ``weights``
    moment-matched in joint space, as is (``feature_blob``) and with each of ``depth_profile.PARTS``' feature
    groups set to the ``true`` features (``part_features``); the twin at the mirror image of each."""
    out = {}
    for name, groups in {"feature_blob": (), **PARTS}.items():
        truth, twin = mirrored_points(model, *part_features(model, weights, c, true, groups))
        out[name] = (truth[0], twin[0])
    return out


def _read_motion_blobs(scorer, frame, model, weights: np.ndarray, c: int, poses: tuple, position: np.ndarray, t: int,
                       vel_std: float, true: np.ndarray, errors: dict) -> tuple:
    """``--read-motion``'s pair (truth, twin) of point distributions: primitive ``c``'s feature blob (its mirror
    image for the twin) with its motion read from the frame's flows at each pose (``read_motion``); the true
    pose's read and blob motion errors against the ``true`` features are added to ``errors``."""
    from harness import geometry
    from harness.engine.features import ANGLE_RATES, BASE_LINEAR, mirror_features, mirror_variances

    mean, var = (a[0] for a in part_features(model, weights, c, true, ()))
    out = []
    for k, quat in enumerate(poses):
        m, v = (mean, var) if k == 0 else (mirror_features(mean), mirror_variances(var))
        rot = geometry.to_matrix(quat[t])
        blob = posture_points(model, m[None], v[None])[0]
        img = scorer.image(frame, rot[None], position[None], blob)
        read_mean, read_var = read_motion(model, frame, rot, position, m, v, img, vel_std, scorer.config.noise_px)
        if k == 0:
            for name, group in (("rates", ANGLE_RATES), ("base_linear", BASE_LINEAR)):
                errors["blob_" + name].append((m - true)[group])
                errors["read_" + name].append((read_mean - true)[group])
        out.append(posture_points(model, read_mean[None], read_var[None])[0])
    return tuple(out)


def read_motion(model, frame, rot: np.ndarray, position: np.ndarray, mean: np.ndarray, var: np.ndarray, img,
                vel_std: float, noise_px: float, outlier: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Features ``mean``, ``var`` ``(106,)`` with the motion (angle rates, the base's linear and angular velocity)
    replaced by its Gaussian posterior given the frame's flow velocities, at the pose ``rot``, ``position``: each
    flow assigned softly to the visible model points by position alone (``img``, one hypothesis's projection, the
    pixel noise ``noise_px`` added, the outlier share ``outlier`` uniform over the image); each point's target the
    assigned flows' mean velocity, known to ``vel_std`` px/s; the image velocity linear in the motion at the mean
    angles, ``d(u, v)/dt = Pi R (J theta_dot + v + omega x x)``; the prior the features' own Gaussian."""
    from harness.engine.features import ANGLE_RATES, BASE_ANGULAR

    flows, intr = frame.flows, frame.intr
    pix, cov, vis = img.pix[0], img.pix_cov[0] + noise_px**2 * np.eye(2), img.visibility[0]
    d = flows[:, None, :2] - pix[None]
    mahalanobis = np.einsum("mpi,pij,mpj->mp", d, np.linalg.inv(cov), d)
    density = vis[None] / max(vis.sum(), 1e-12) * np.exp(-0.5 * mahalanobis) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))
    inlier = (1 - outlier) * density
    resp = inlier / (inlier.sum(1, keepdims=True) + outlier / (intr.width * intr.height))
    mass = resp.sum(0)
    used = mass > 1e-3
    target = resp[:, used].T @ flows[:, 2:4] / mass[used, None]
    a = image_velocity_map(model, intr, mean[:ANGLE_RATES.start], rot, position, used)
    motion = np.r_[ANGLE_RATES.start:BASE_ANGULAR.stop]
    prior_mean, prior_precision = mean[motion], 1.0 / var[motion]
    precision = np.einsum("q,qil,qim->lm", mass[used], a, a) / vel_std**2 + np.diag(prior_precision)
    covariance = np.linalg.inv(precision)
    out_mean, out_var = mean.copy(), var.copy()
    out_mean[motion] = covariance @ (np.einsum("q,qil,qi->l", mass[used], a, target) / vel_std**2
                                     + prior_precision * prior_mean)
    out_var[motion] = np.diag(covariance)
    return out_mean, out_var


def image_velocity_map(model, intr, angles: np.ndarray, rot: np.ndarray, position: np.ndarray,
                       used: np.ndarray) -> np.ndarray:
    """``(Q, 2, 56)``: the model points ``used`` (a mask or indices) at ``angles``, the base at ``rot``,
    ``position`` (camera frame): each point's image velocity (px/s) as a linear map of the motion ``(angle rates,
    v, omega)`` (the base's velocities in its own frame), ``Pi R (J theta_dot + v + omega x x)``, the engine's
    ``transform`` at a static camera."""
    from harness.body.kinematics import forward_points_and_jacobians

    qpos = np.concatenate([[0, 0, 0, 1, 0, 0, 0], angles])
    x, jac = forward_points_and_jacobians(model.body, qpos, model.points.body[used], model.points.local[used], "base")
    cam = x @ rot.T + position
    z = cam[:, 2]
    proj = np.zeros((len(x), 2, 3))
    proj[:, 0, 0], proj[:, 0, 2] = intr.fx / z, -intr.fx * cam[:, 0] / z**2
    proj[:, 1, 1], proj[:, 1, 2] = intr.fy / z, -intr.fy * cam[:, 1] / z**2
    minus_skew = np.zeros((len(x), 3, 3))          # omega x x = minus_skew @ omega
    minus_skew[:, 0, 1], minus_skew[:, 0, 2], minus_skew[:, 1, 2] = x[:, 2], -x[:, 1], x[:, 0]
    minus_skew[:, 1, 0], minus_skew[:, 2, 0], minus_skew[:, 2, 1] = -x[:, 2], x[:, 1], -x[:, 0]
    return np.einsum("qij,jk,qkl->qil", proj, rot,
                     np.concatenate([jac, np.broadcast_to(np.eye(3), (len(x), 3, 3)), minus_skew], axis=2))


def _sampled_margin(scorer, frame, model, belief: np.ndarray, samples: int, rng: np.random.Generator, poses: list,
                    n_eff: float) -> float:
    """One frame's truth minus twin under ``samples`` postures drawn from the belief (a state by its posterior,
    then every feature from that state's Gaussian), the twin at each draw's mirror image: each pose's score the
    log mean over the draws of the frame's tempered joint likelihood at one posture (the flows share it)."""
    from harness.engine.features import mirror_features
    from harness.engine.transform import JointGaussians, state_point_distributions
    from scipy.special import logsumexp

    states = rng.choice(belief.size, size=samples, p=belief / belief.sum())
    draws = model.db_means[states] + rng.standard_normal((samples, model.db_means.shape[1])) * np.sqrt(
        model.db_covars[states])
    score = []
    for (quat, position), features in zip(poses, (draws, mirror_features(draws))):
        dists = state_point_distributions(model.body, JointGaussians.from_features(features, np.zeros_like(features)),
                                          model.points, model.spread)
        ll = scorer.pose_log_likelihood(frame, np.repeat(quat[None], samples, 0), np.repeat(position[None], samples, 0),
                                        dists, np.arange(samples), n_eff=n_eff)
        score.append(logsumexp(ll) - np.log(samples))
    return float(score[0] - score[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.add_argument("--offsets", type=float, nargs="*", default=[0.1, 0.2],
                    help="rad: std of the true angles' fixed offsets (and of every angle) to score at")
    ap.add_argument("--plot", default=None, metavar="PNG", help="also draw the per-class margins into this file")
    ap.add_argument("--samples", type=int, default=0, metavar="K",
                    help="also score under K postures drawn from the belief each frame (module docstring)")
    ap.add_argument("--recovered", type=float, default=None, metavar="STD",
                    help="also score each path at the posture recovered along it, every angle with this std (rad)")
    ap.add_argument("--read-motion", type=float, default=None, metavar="STD",
                    help="also score the blob with its motion read from the flows at each path (px/s; docstring)")
    ap.add_argument("--parts", action="store_true",
                    help="also score the belief's blob with the true angles, motion, rates or base velocity")
    args = ap.parse_args()
    runs = dev_runs.selected(args)
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(partial(_one, offsets=tuple(args.offsets), recovered=args.recovered, samples=args.samples,
                                      parts=args.parts, read_std=args.read_motion), runs, args)
    modes = list(rows[0]["margin"])
    print("the truth's score minus its exact twin's over the clip (tempered nats): median over runs (share of runs "
          "the truth scores higher)")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        by_class = defaultdict(list)
        for r in sub:
            by_class[r["class"]].append(r)
        print(f"{cond} ({len(sub)} runs)")
        posture = {k: np.median([r["posture"][k] for r in sub]) for k in sub[0]["posture"]}
        print(f"  the belief's posture along the true path (rad, rms over the moved angles, median over runs): error "
              f"{posture['error']:.3f} (the blob's std {posture['blob_std']:.3f}), of which constant over the clip "
              f"{posture['offset']:.3f} and varying {posture['varying']:.3f}")
        if "read_rates" in posture:
            print(f"  the motion read from the flows at the true pose against the belief's (rms over the frames, "
                  f"median over runs): angle rates {posture['read_rates']:.3f} against {posture['blob_rates']:.3f} "
                  f"rad/s, the base's velocity {posture['read_base_linear']:.3f} against "
                  f"{posture['blob_base_linear']:.3f} m/s")
        if "recovered_error" in posture:
            print(f"  the angles recovery finds handed the true base path (the gt_base run's), the same frames: error "
                  f"{posture['recovered_error']:.3f}, of which constant {posture['recovered_offset']:.3f} and varying "
                  f"{posture['recovered_varying']:.3f}")
        print(f"  {'class':13s} " + " ".join(f"{m:>15s}" for m in modes))
        for name, group in [("all", sub)] + sorted(by_class.items()):
            cells = []
            for m in modes:
                v = np.array([r["margin"][m] for r in group])
                cells.append(f"{np.median(v):8.1f} ({np.mean(v > 0):.2f})")
            print(f"  {name:13s} " + " ".join(f"{c:>15s}" for c in cells))
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s")
    if args.plot:
        plot(rows, args.plot)
        print(f"wrote {args.plot}")


def plot(rows: list[dict], path: str) -> None:
    """Per condition a panel: per class, the median margin over the twin under each posture (a marker each)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    classes = sorted({r["class"] for r in rows})
    # From the least posture knowledge to the most: the blob, the draws and recoveries, the offsets widest first.
    rank = {"blob": 0, "true": 99}
    modes = sorted(rows[0]["margin"], key=lambda m: rank.get(m, 50 - float(m[3:]) if m.startswith("off") else 1))
    fig, axes = plt.subplots(1, len(conditions), figsize=(6 * len(conditions), 4), sharey=True, squeeze=False)
    for ax, cond in zip(axes[0], conditions):
        for j, m in enumerate(modes):
            med = [np.median([r["margin"][m] for r in rows if r["condition"] == cond and r["class"] == c] or [np.nan])
                   for c in classes]
            ax.plot(np.arange(len(classes)) + 0.12 * (j - (len(modes) - 1) / 2), med, "o", label=m)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_xticks(range(len(classes)), classes, rotation=45, ha="right")
        ax.set_title(cond)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("truth minus exact twin (nats, median)")
    axes[0][0].legend(title="weighed at", fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, metadata={"Software": None})
    plt.close(fig)


if __name__ == "__main__":
    main()
