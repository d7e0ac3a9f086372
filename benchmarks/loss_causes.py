"""Why the engine loses a run: did its tracks miss a better path (search), or does a wrong class explain the
flows better than the true class on the true path (model)?

    MUJOCO_GL=egl python benchmarks/loss_causes.py [--scenario scenarios/default.yaml] [--seed S ...]
        [--amount 0.0 0.4] [--limit N] [--class wave ...] [--jobs 2] [--set KEY=VALUE ...]

For every selected run the engine tracks the clip (its causal pass); the winner is the final track with the
most evidence, and the causal answer is the class posterior's argmax. Along the true baselink path, every
primitive's evidence is what a track of that primitive following the truth would gather
(``scoring.path_class_evidence``, the same evidence a track accumulates). A lost run is

- a **search** failure when the true class along the true path has more evidence than the winner: a better
  explanation existed and the tracks did not find it (a wider search, a better start, could fix it);
- a **model** failure otherwise: the winner's own path explains the flows better than the truth does under the
  true class, so no search can fix it; the likelihood, the tempering or the database must change.

Per class, the **pose freedom** is the evidence of the class's best final track minus that class along the true
path: what tracking the pose (fitted to the flows frame by frame) is worth to the class. A class that gains
more from it than the true class wins without being right.

For each model failure whose winner kept its track id from the start (a re-injected track's first frames are its
parent's), the gap between the winner's class on the winner's path and the true class on the true path is
**split by body part**: each frame's tempered per-flow log-likelihoods, weighted by the states' posterior
responsibilities (a linearisation of the frame's ``log sum_k alpha_k b_k``), summed over the flows of each part's
markers (ground truth, for this diagnosis only; outlier rows apart). It tells which part of the body the
winner explains better. ``--seed`` replaces the scenario's seed (development seeds for choices); ``--class``
keeps the runs of those test classes.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import dev_runs

# Body parts, by the humanoid's segment names (the clavicles go with the trunk).
PARTS = ("trunk", "left arm", "right arm", "left leg", "right leg", "outlier")
_ARM = ("humerus", "radius", "wrist", "hand")
_LEG = ("femur", "tibia", "foot", "toes")


def part_of(segment: str) -> str:
    side = {"l": "left", "r": "right"}.get(segment[0])
    if side and segment[1:] in _ARM:
        return f"{side} arm"
    if side and segment[1:] in _LEG:
        return f"{side} leg"
    return "trunk"


def evidence_by_flow(model, config, obs, positions, quats, primitive, pose_given: bool = False) -> list:
    """Per frame, ``(M,)`` each flow's share of the evidence a track of ``primitive`` following the path gains:
    the tempered per-flow log-likelihoods of the active states, weighted by their posterior responsibilities
    after the frame (empty for a frame without flows). ``pose_given``: the recursion scores the flows as at a
    given pose (``Scorer.recognise``), as the shares do."""
    from harness import geometry
    from harness.engine.frame import observation_frames
    from harness.engine.recognition import Recognizer
    from harness.engine.scoring import Scorer

    scorer = Scorer(model, config)
    rec = Recognizer(model.db, config.start_spread, config.prune).restrict([primitive])
    out, started = [], False
    for frame in observation_frames(obs, config):
        t = frame.index
        if not (started or frame.has_flows):
            out.append(np.zeros(0))
            continue
        rec.predict()
        started = True
        share = np.zeros(len(frame.flows))
        if frame.has_flows:
            active = np.flatnonzero(rec.active().ravel())
            rot = np.repeat(geometry.to_matrix(quats[t])[None], len(active), axis=0)
            img = scorer.image(frame, rot, np.repeat(positions[t][None], len(active), axis=0), model.dists, active)
            per_flow = scorer.per_flow(frame, img)[:, :len(frame.flows)]
            scale = min(len(frame.flows), config.n_eff_recognition) / len(frame.flows)
            log_b = per_flow.sum(axis=1) * scale
            w = np.log(rec.posterior.ravel()[active]) + log_b
            w = np.exp(w - w.max())
            share = (w / w.sum()) @ per_flow * scale
        out.append(share)
        scorer.recognise(frame, [rec], positions[t], quats[t], pose_given=pose_given)
    return out


def _one(job) -> dict:
    run, overrides = job
    from harness.engine.scoring import path_class_evidence
    from harness.evaluation import pipeline

    inputs = pipeline.run_inputs(run)
    tracker = dev_runs.tracker_for(inputs, overrides)
    est = tracker.run(inputs.obs)
    classes = list(tracker.model.db.classes_)
    final = tracker.records[-1].tracks
    class_of = [classes[int(np.argmax(t.joint_posterior.sum(axis=1)))] for t in final]
    best_track = {c: max((t.log_evidence for t, k in zip(final, class_of) if k == c), default=np.nan) for c in classes}
    winner = int(np.argmax([t.log_evidence for t in final]))
    along_truth = path_class_evidence(tracker.model, tracker.config, inputs.obs, inputs.truth.base_pos_cam,
                                      inputs.truth.base_quat_cam)
    row = {"key": run.key, "seed": run.config.seed, "condition": run.condition_label, "class": run.test_class,
           "answer": classes[int(np.argmax(est.class_posterior[-1]))], "winner_class": class_of[winner],
           "winner": final[winner].log_evidence, "truth": dict(zip(classes, along_truth)), "best_track": best_track}
    if row["answer"] != run.test_class and not _search_failure(row):
        row["by_part"] = _gap_by_part(tracker, inputs, final[winner].track_id, classes.index(class_of[winner]),
                                      classes.index(run.test_class))
    return row


def _search_failure(row: dict) -> bool:
    """The true class along the true path has more evidence than the winning track (module docstring)."""
    return row["truth"][row["class"]] > row["winner"]


def _gap_by_part(tracker, inputs, track_id, winner_class, true_class) -> dict | None:
    """The winner's class on its path minus the true class on the true path, split by body part (module
    docstring); None when the winner's track id does not span the clip."""
    truth = inputs.truth
    pos, quat = truth.base_pos_cam.copy(), truth.base_quat_cam.copy()
    first = next(r.index for r in tracker.records if r.tracks)
    for r in tracker.records[first:]:
        mine = [t for t in r.tracks if t.track_id == track_id]
        if not mine:
            return None
        pos[r.index], quat[r.index] = mine[0].position, mine[0].quat
    model, config = tracker.model, tracker.config
    won = evidence_by_flow(model, config, inputs.obs, pos, quat, winner_class)
    true = evidence_by_flow(model, config, inputs.obs, truth.base_pos_cam, truth.base_quat_cam, true_class)
    body = inputs.body.model
    segment = np.array([part_of(body.body(int(b)).name) for b in truth.markers.body] + ["outlier"])
    gap = dict.fromkeys(PARTS, 0.0)
    for a, b, ids in zip(won, true, truth.marker_ids):
        for part, d in zip(segment[np.asarray(ids, dtype=int)], a - b):
            gap[part] += float(d)
    return gap


def _median(values) -> str:
    values = [v for v in values if np.isfinite(v)]
    return f"{np.median(values):6.1f} ({len(values):3d})" if values else "     -      "


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.add_argument("--class", dest="classes", nargs="*", default=None, help="only runs of these test classes")
    args = ap.parse_args()
    runs = [r for r in dev_runs.selected(args, pick=np.random.default_rng(0))
            if args.classes is None or r.test_class in args.classes]
    if not runs:
        raise SystemExit("no runs selected (check --amount, --class and the scenario's classes)")
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(_one, runs, args)

    lost = [r for r in rows if r["answer"] != r["class"]]
    for r in lost:
        r["search"] = _search_failure(r)
    print(f"{'run':22s} {'seed':>5s} {'condition':22s} {'class':>12s} {'answer':>12s} {'winner':>12s} "
          f"{'truth-winner':>12s} {'own track-winner':>16s}   (tempered nats)")
    for r in lost:
        print(f"{r['key']:22s} {r['seed']:5d} {r['condition']:22s} {r['class']:>12s} {r['answer']:>12s} "
              f"{r['winner_class']:>12s} {r['truth'][r['class']] - r['winner']:12.1f} "
              f"{r['best_track'][r['class']] - r['winner']:16.1f}")
    print("\nlost runs (causal): search failures (the true class on the true path beats the winner) / model failures")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in lost if r["condition"] == cond]
        n = sum(r["condition"] == cond for r in rows)
        print(f"  {cond}: {len(sub)} of {n} lost; search {sum(r['search'] for r in sub)}, "
              f"model {sum(not r['search'] for r in sub)}")
    by_class = {c: [r for r in lost if r["class"] == c] for c in sorted({r["class"] for r in lost})}
    print("  by true class: " + ", ".join(f"{c} {sum(r['search'] for r in rs)}/{sum(not r['search'] for r in rs)}"
                                          for c, rs in by_class.items()))
    split = [r for r in lost if r.get("by_part") is not None]
    if split:
        print(f"\nthe gap (winner's class on its path minus the true class on the true path) by body part, "
              f"{len(split)} model failures whose winner spans the clip: median [quartiles], tempered nats")
        for part in PARTS:
            v = np.array([r["by_part"][part] for r in split])
            print(f"  {part:>10s} {np.median(v):7.1f} [{np.percentile(v, 25):6.1f}, {np.percentile(v, 75):6.1f}]")
    print("\npose freedom: best final track minus the class along the true path, median (runs with a live track)")
    classes = list(rows[0]["truth"])
    print(f"  {'class':>12s} {'as the true class':>18s} {'as another class':>18s}")
    for c in classes:
        own = [r["best_track"][c] - r["truth"][c] for r in rows if r["class"] == c]
        other = [r["best_track"][c] - r["truth"][c] for r in rows if r["class"] != c]
        print(f"  {c:>12s} {_median(own):>18s} {_median(other):>18s}")
    print(f"\n{len(rows)} runs, {len(lost)} lost, in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
