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
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from functools import partial

import numpy as np

import dev_runs

SCALES = np.array([0.8, 0.9, 1.0, 1.1, 1.2, 1.35, 1.5])
OFFSETS_M = np.linspace(-0.4, 0.4, 17)
PITCHES_DEG = np.arange(-20.0, 21.0, 5.0)
TRUE = int(np.flatnonzero(SCALES == 1.0)[0])


def _one(job, position_scale: float = 1.0, top_state: bool = False) -> dict:
    run, overrides = job
    from harness import geometry
    from harness.engine.frame import observation_frames
    from harness.engine.recognition import Recognizer
    from harness.engine.scoring import Scorer
    from harness.evaluation import pipeline

    inputs = pipeline.run_inputs(run)
    obs, truth = inputs.obs, inputs.truth
    tracker = dev_runs.tracker_for(inputs, overrides)
    model, cfg = tracker.model, tracker.config
    scorer = Scorer(model, cfg)
    c = list(model.db.classes_).index(run.test_class)
    rec = Recognizer(model.db, cfg.start_spread, cfg.prune).restrict([c])
    pos, quat = truth.base_pos_cam, truth.base_quat_cam
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
        rec.predict()
        started = True
        if frame.has_flows:
            rows = np.where(rec.active(), rec.state_posterior, 0.0)
            rows[np.arange(len(rows)) != c] = 0.0
            if top_state:
                rows = (np.arange(rows.size) == rows.argmax()).astype(float).reshape(rows.shape)
            dists = model.dists.mixtures(rows.reshape(1, -1) / rows.sum())
            dists = dataclasses.replace(dists, pos_cov=dists.pos_cov * position_scale)
            p = (SCALES[:, None, None, None] * pos[t] + offsets).reshape(-1, 3)
            q = geometry.multiply(pitches, np.broadcast_to(quat[t], (S * D * P, 4)))
            total += scorer.pose_log_likelihood(frame, q, p, dists, n_eff=cfg.n_eff_filter).reshape(S, D, P)
        scorer.recognise(frame, [rec], pos[t][None], quat[t][None])
    flat = total.reshape(S, -1)
    best = np.unravel_index(flat[int(flat.max(axis=1).argmax())].argmax(), (D, P))
    return {"key": run.key, "condition": run.condition_label, "class": run.test_class,
            "profile": flat.max(axis=1), "exact": total[:, D // 2, P // 2],
            "offset_m": float(OFFSETS_M[best[0]]), "pitch_deg": float(PITCHES_DEG[best[1]])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.add_argument("--position-scale", type=float, default=1.0, help="the weighing's position covariances x this")
    ap.add_argument("--top-state", action="store_true", help="the belief's most probable state instead of its blob")
    args = ap.parse_args()
    runs = dev_runs.selected(args)
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(partial(_one, position_scale=args.position_scale, top_state=args.top_state), runs, args)
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
