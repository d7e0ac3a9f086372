"""Where a stream's frames are lost, from flows (``full``) and with the true base pose (``gt_base``).

    MUJOCO_GL=egl python benchmarks/stream_losses.py [--scenario scenarios/stream.yaml] [--seed S ...]
        [--amount 0.0 0.3] [--limit N] [--jobs 2] [--set KEY=VALUE ...]

Every selected stream is tracked twice, keeping the engine's frame records: from the flows, and given the true
base pose. Each frame's online label (``engine.switching.online_labels``, as the evaluation scores it) is then
compared with the true one:

- **by position in its true segment**: the first 10 frames (0.33 s at 30 fps), frames 10-30, the last 10, and
  the middle; and what was said instead: the segment before (the recursion still holds the previous
  primitive), the segment after, or another primitive;
- **per class**, and the commonest confusions;
- **the leader's orientation error** (the angle between the leading track's base orientation and the truth)
  at the frames said right and wrong;
- **the decision among the tracks**: the same records decided by other rules over the live tracks. The engine
  mixes the tracks' class posteriors weighted by the softmax of their evidence since their start. Also:
  equal weights; the evidence gathered over the last ``W`` frames only (a track younger than that: since its
  start); and, as a bound no rule can pass, the live track that believes the true primitive most (it reads the
  truth, so it is not a method). If the bound is near the engine's rule, the tracks' beliefs themselves are
  wrong, not the choice among them.

``--seed`` replaces the scenario's seed (development seeds for choices); ``--set`` changes engine settings of
both passes.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import numpy as np

import dev_runs

POSITIONS = ("first 10", "10-30", "middle", "last 10")
WINDOWS = (15, 30)
SAID = ("right", "previous", "next", "other")


def position(i: int, n: int) -> str:
    """The bin of frame ``i`` of a true segment of ``n`` frames."""
    if i < 10:
        return "first 10"
    if i < 30:
        return "10-30"
    return "last 10" if n - i <= 10 else "middle"


def mixture(tracks, log_weights: np.ndarray) -> np.ndarray:
    """The class posterior ``(C,)`` of the tracks mixed with weights ``softmax(log_weights)`` (the engine's rule
    with other weights)."""
    from harness.engine.records import mixed_log_class_posterior

    return np.exp(mixed_log_class_posterior(tracks, log_weights))


def decided(records, labels: np.ndarray, classes: list[str]) -> dict[str, np.ndarray]:
    """Class posteriors ``(T, C)`` of the frame records under each decision rule (module docstring)."""
    first = next(i for i, r in enumerate(records) if r.tracks)
    history: dict[int, list[tuple[int, float]]] = {}     # a track's (frame, evidence) since its start
    rules: dict[str, list] = {"engine": [], "equal weights": [], **{f"last {w} frames": [] for w in WINDOWS},
                              "bound: the track believing the truth most": []}
    for t, record in enumerate(records[first:], start=first):
        evidence = np.array([tr.log_evidence for tr in record.tracks])
        for tr in record.tracks:
            history.setdefault(tr.track_id, []).append((t, tr.log_evidence))
        rules["engine"].append(mixture(record.tracks, evidence))
        rules["equal weights"].append(mixture(record.tracks, np.zeros(len(evidence))))
        for w in WINDOWS:
            gained = []
            for tr in record.tracks:
                h = history[tr.track_id]
                before = [e for s, e in h if s <= t - w]
                gained.append(tr.log_evidence - (before[-1] if before else h[0][1]))
            rules[f"last {w} frames"].append(mixture(record.tracks, np.array(gained)))
        beliefs = np.array([tr.joint_posterior.sum(axis=1) for tr in record.tracks])
        truth = classes.index(labels[t]) if labels[t] in classes else None
        rules["bound: the track believing the truth most"].append(
            rules["engine"][-1] if truth is None else beliefs[np.argmax(beliefs[:, truth])])
    return {k: np.vstack([np.repeat(np.array(v[:1]), first, axis=0), np.array(v)]) for k, v in rules.items()}


def analyse(run, overrides: dict) -> dict:
    """One stream, both passes: per method the online labels, the leader's orientation error per frame and the
    stream scores of every decision rule."""
    from harness.engine.switching import STREAM_MIN_FRAMES, online_labels
    from harness.evaluation.pipeline import run_inputs
    from harness.evaluation.stream_metrics import stream_scores

    inputs = run_inputs(run)
    labels = np.asarray(inputs.labels)
    classes = list(inputs.classes)
    truth = inputs.truth
    out = {"key": run.key, "seed": run.config.seed, "condition": run.condition_label, "labels": labels}
    for method, given in (("full", None), ("gt_base", (truth.base_pos_cam, truth.base_quat_cam))):
        tracker = dev_runs.tracker_for(inputs, overrides)
        est = tracker.run(inputs.obs, base_pose=given)
        said = np.asarray(classes)[online_labels(est.class_posterior, STREAM_MIN_FRAMES)]
        dot = np.clip(np.abs(np.sum(est.filter_quat * truth.base_quat_cam, axis=1)), 0.0, 1.0)
        rules = {name: stream_scores(np.asarray(classes)[online_labels(post, STREAM_MIN_FRAMES)], labels,
                                     inputs.obs.fps)
                 for name, post in decided(tracker.records, labels, classes).items()}
        out[method] = {"said": said, "rotation_err_deg": np.rad2deg(2 * np.arccos(dot)), "rules": rules}
    return out


def by_position(results: list[dict], method: str) -> dict:
    """Frames and their labels by position in the true segment: ``{bin: Counter(said kind)}`` and the leader's
    orientation errors at frames said right and wrong."""
    from harness.motion.stream import TRANSITION, label_segments

    kinds = {b: Counter() for b in POSITIONS}
    errors = {True: [], False: []}
    for res in results:
        said = res[method]["said"]
        segments = [s for s in label_segments(res["labels"]) if s.label != TRANSITION]
        for k, seg in enumerate(segments):
            before = segments[k - 1].label if k else None
            after = segments[k + 1].label if k + 1 < len(segments) else None
            for t in range(seg.start, seg.stop):
                kind = ("right" if said[t] == seg.label else "previous" if said[t] == before
                        else "next" if said[t] == after else "other")
                kinds[position(t - seg.start, seg.stop - seg.start)][kind] += 1
                errors[kind == "right"].append(res[method]["rotation_err_deg"][t])
    return {"kinds": kinds, "rotation": errors}


def per_class(results: list[dict], method: str) -> tuple[dict, Counter]:
    """Per true class: (frames, frames said wrong); and the confusions ``(true, said)``."""
    from harness.motion.stream import TRANSITION

    frames, wrong, confusions = Counter(), Counter(), Counter()
    for res in results:
        for true, said in zip(res["labels"], res[method]["said"]):
            if true == TRANSITION:
                continue
            frames[true] += 1
            if said != true:
                wrong[true] += 1
                confusions[(str(true), str(said))] += 1
    return {c: (frames[c], wrong[c]) for c in sorted(frames)}, confusions


def report(results: list[dict]) -> None:
    for condition in sorted({r["condition"] for r in results}):
        group = [r for r in results if r["condition"] == condition]
        print(f"\n=== {condition}: {len(group)} streams")
        for method in ("full", "gt_base"):
            pos = by_position(group, method)
            n_all = sum(sum(c.values()) for c in pos["kinds"].values())
            n_right = sum(c["right"] for c in pos["kinds"].values())
            print(f"\n{method}: frame accuracy {n_right / n_all:.3f} over {n_all} labelled frames "
                  f"(mean per stream {np.mean([r[method]['rules']['engine']['frame_accuracy'] for r in group]):.3f})")
            print(f"  {'position':10s} {'frames':>7s} " + " ".join(f"{k:>9s}" for k in SAID))
            for b in POSITIONS:
                c = pos["kinds"][b]
                n = sum(c.values())
                print(f"  {b:10s} {n:7d} " + " ".join(f"{c[k] / max(n, 1):9.2f}" for k in SAID))
            if method == "full":
                rot = pos["rotation"]
                print(f"  leader's orientation error, median: {np.median(rot[True]):.1f} deg at frames said right, "
                      f"{np.median(rot[False]):.1f} deg at frames said wrong")
            classes, confusions = per_class(group, method)
            print("  wrong frames per class: " + ", ".join(f"{c} {w}/{n}" for c, (n, w) in classes.items()))
            print("  commonest confusions (true -> said): " + ", ".join(
                f"{t} -> {s} {n}" for (t, s), n in confusions.most_common(6)))
            print("  decision among the tracks (mean frame accuracy, F1@25; streams better / worse than the "
                  "engine's rule by more than 0.02):")
            engine = np.array([r[method]["rules"]["engine"]["frame_accuracy"] for r in group])
            for rule in group[0][method]["rules"]:
                fa = np.array([r[method]["rules"][rule]["frame_accuracy"] for r in group])
                f1 = np.array([r[method]["rules"][rule]["f1_25"] for r in group])
                print(f"    {rule:42s} {fa.mean():.3f}  {f1.mean():.3f}  {int((fa > engine + 0.02).sum())} / "
                      f"{int((fa < engine - 0.02).sum())}")


def main() -> None:
    from harness.engine.config import settings_from_strings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.set_defaults(scenario="scenarios/stream.yaml", amount=[0.0, 0.3])
    args = ap.parse_args()
    overrides = settings_from_strings(args.set)
    runs = dev_runs.selected(args)
    print(f"{len(runs)} streams, both passes ({args.jobs} processes)", flush=True)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
        results = list(pool.map(analyse, runs, [overrides] * len(runs)))
    report(results)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
