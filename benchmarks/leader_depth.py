"""Is the reported pose lost in the choice of the leader among the live tracks?

    MUJOCO_GL=egl python benchmarks/leader_depth.py [--scenario scenarios/default.yaml] [--seed S]
        [--amount 0.0 0.4] [--limit N] [--jobs 2] [--set KEY=VALUE ...]

For every frame of every run: the leading track's depth error ``|log(depth / true depth)|`` (the leader of
``FrameRecord.decision``, whose pose the causal estimate reports), beside the tracks alive at that frame that
hypothesise the leader's primitive: the mean error of one of them taken at random, and the error of the best of
them. Printed per condition over four spans of the clip, over the frames where the leader has such siblings.
"The best" reads the truth, so it bounds what any rule choosing among a primitive's tracks could gain; the
random one is what a rule blind to depth would get. Then the heading error (degrees, as ``evaluate`` measures
it, of the reported configuration's base) over every frame: the leader's, its best sibling's, and the best of
all live tracks' (any primitive), averaged over the clip per run and over the runs. ``--seed`` replaces the
scenario's seed (development seeds for choices, the scenario's own for reporting).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import dev_runs

SPANS = ((0.0, 0.2), (0.2, 0.5), (0.5, 0.8), (0.8, 1.0))


def _one(job) -> tuple[str, np.ndarray, np.ndarray]:
    """``(condition, rows, headings)``: per frame with tracks, its place in the clip (0-1), the leader's depth
    error, a random sibling's (the mean over the siblings, the leader among them) and the best sibling's, and how
    many siblings; the mean heading errors over the clip of the leader, its best sibling and the best live track
    (frames before the first tracks take the first frame's tracks, as the causal estimate does)."""
    run, overrides = job
    from harness.evaluation import pipeline
    from harness.evaluation.metrics import heading_error_curve

    inputs = pipeline.run_inputs(run)
    obs, truth = inputs.obs, inputs.truth
    tracker = dev_runs.tracker_for(inputs, overrides)
    tracker.run(obs)
    first = next(i for i, r in enumerate(tracker.records) if r.tracks)
    rows, headings = [], []
    for i in range(len(tracker.records)):
        rec = tracker.records[max(i, first)]           # before the first tracks, the first frame's tracks
        tracks = rec.tracks
        _, lead = rec.decision()
        # A track of one primitive is named after it (``walk/lead``, ``walk/lead>twin@12``).
        is_sibling = np.array([t.origin.split("/")[0] == lead.origin.split("/")[0] for t in tracks])
        n = len(tracks)
        heading = np.array(heading_error_curve(np.array([t.qpos[3:7] for t in tracks]),
                                               np.repeat(truth.base_quat_cam[i][None], n, axis=0),
                                               np.repeat(truth.camera_rot[i][None], n, axis=0), n))
        headings.append((heading[next(k for k, t in enumerate(tracks) if t is lead)], heading[is_sibling].min(),
                         heading.min()))
        if i < first:
            continue
        siblings = [t for t, s in zip(tracks, is_sibling) if s]
        errors = np.abs(np.log(np.array([t.position[2] for t in siblings]) / truth.base_pos_cam[rec.index, 2]))
        lead_error = errors[next(k for k, t in enumerate(siblings) if t is lead)]
        rows.append((rec.index / max(len(obs) - 1, 1), lead_error, errors.mean(), errors.min(), len(errors)))
    return run.condition_label, np.array(rows).reshape(-1, 5), np.mean(headings, axis=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    args = ap.parse_args()
    runs = dev_runs.selected(args, pick=np.random.default_rng(0))
    t0 = time.perf_counter()
    results = dev_runs.map_runs(_one, runs, args)
    print("mean |log(depth / true depth)| over the frames where the leader has siblings of its primitive:")
    for cond in dict.fromkeys(c for c, _, _ in results):
        rows = np.concatenate([r for c, r, _ in results if c == cond])
        print(f"{cond}:")
        for lo, hi in SPANS:
            at = rows[(rows[:, 0] >= lo) & ((rows[:, 0] < hi) | (hi == 1.0)) & (rows[:, 4] > 1)]
            if len(at) == 0:
                continue
            print(f"  clip {lo:.1f}-{hi:.1f}: leader {at[:, 1].mean():.3f}, a sibling at random {at[:, 2].mean():.3f}, "
                  f"the best sibling {at[:, 3].mean():.3f} ({len(at)} frames, {at[:, 4].mean():.1f} siblings)")
    print("\nheading error (deg; mean over the clip, then over the runs): the leader, its best sibling, the best "
          "live track (the last two read the truth)")
    for cond in dict.fromkeys(c for c, _, _ in results):
        h = np.array([h for c, _, h in results if c == cond])
        print(f"{cond}: leader {h[:, 0].mean():.1f}, best sibling {h[:, 1].mean():.1f}, best live track "
              f"{h[:, 2].mean():.1f} ({len(h)} runs)")
    print(f"\n{len(runs)} runs in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
