"""Does the evidence the tracks are scored by point at the true global pose?

    MUJOCO_GL=egl python benchmarks/pose_evidence.py [--scenario scenarios/default.yaml] [--seed S]
        [--amount 0.0 0.4] [--limit N] [--jobs 2]

For every run of the scenario at the given occlusion amounts, the database's evidence over the whole clip
(``harness.engine.scoring.path_evidence``: the sum over frames of the forward recursion's normaliser, with the
engine's own tempering and pruning) is computed along the true baselink path and along its alternatives: the
same path turned by +90, 180 and -90 degrees about the body's vertical, and its depth-reflected mirrored twin
(``harness.engine.track.twin``). Prints per run the margin of the truth over each alternative, then the share of
runs in which the truth beats every alternative and the smallest margins. This is what the engine's tracks
rest on: when the truth does not win here, no tracking can choose it. Then, per class, the share of runs
recognised correctly (the final class posterior of the same recursions, ``scoring.path_recognition``) along the
true path, along its exact twin and along its upright twin: a both-handed database (``database.mirrored``)
should recognise the twin's mirrored body as well as the truth (the upright twin, reflected through the vertical
plane instead of the camera's, is not the image's twin under an elevated camera). ``--seed`` replaces the scenario's seed
(development seeds for choices, the scenario's own for reporting).

Then the causal chooser (``causal_choice``): with the true path and its alternatives known exactly, the heading
error of reporting at every frame the path with the most evidence so far, per condition, for all five
alternatives and for the turns and the twins apart, by the motion the flows have shown so far, and per class.
``--set likelihood.recognise_velocities=false`` scores the flows' joint likelihood instead of the velocities given the
positions. For the twins misread, the truth's evidence margin over them.

Then, for the first frames with flows, how much each frame tells the truth from each alternative (``print_early``).

``--shifts 2 4 6`` also measures how far each run's answer is from the pose's errors: every primitive's
evidence (``scoring.path_class_evidence``, a track that believed only it) along the true path and along the
true path shifted sideways as a whole (camera x) by each of these centimetres, both ways. Per class it prints
the true class's margin over the best other class at the true path (median and smallest), and in how many runs
a shift of at most each size gives another class the lead.

``--turns 10 20 30 45 60`` also scores the true path turned about the body's vertical by each of these angles
(degrees), both ways, and prints per class the truth's margin over each turned path (median over runs) and how
often the truth beats every one of them: how sharply the evidence tells the heading near the truth, apart from
the quarter and half turns above.
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np

import dev_runs

ALTERNATIVES = ("turn+90", "turn180", "turn-90", "twin", "twin_upright")
CURVE_POINTS = 10
EARLY_FRAMES = 8        # the first frames with flows whose per-frame margins ``print_early`` shows


def _one(job, shifts: tuple = (), turns: tuple = ()) -> dict:
    run, overrides = job
    from harness.evaluation.metrics import heading_error_curve
    from harness.engine.model import EngineModel
    from harness.engine.track import turned, twin
    from harness.engine.scoring import Scorer, path_class_evidence, path_recognition
    from harness.evaluation import pipeline
    from harness.evaluation.scenario import tracker_config

    inputs = pipeline.run_inputs(run)
    obs, truth = inputs.obs, inputs.truth
    tc = tracker_config(run.config).with_values(overrides)
    scorer = Scorer(EngineModel.build(inputs.db, inputs.body, tc.model.points, tc.model.seed), tc.likelihood)
    pos, quat = truth.base_pos_cam, truth.base_quat_cam
    paths = {"truth": quat, "turn+90": turned(quat, np.pi / 2), "turn180": turned(quat, np.pi),
             "turn-90": turned(quat, -np.pi / 2), "twin": twin(quat),
             "twin_upright": np.array([twin(q[None], g)[0] for q, g in zip(quat, -truth.camera_rot[:, 2, :])])}
    evidence, recognised, per_frame = {}, {}, {}
    for name, q in paths.items():
        per_frame[name], posterior = path_recognition(scorer, tc.belief, obs, pos, q)
        evidence[name] = float(per_frame[name].sum())
        recognised[name] = bool(inputs.db.classes_[posterior[-1].argmax()] == run.test_class)
    # Each path's heading error at every frame, as evaluate measures it (every chooser reads these).
    heading = {n: np.array(heading_error_curve(q, quat, truth.camera_rot, len(quat))) for n, q in paths.items()}
    margins = {}
    true_class = list(inputs.db.classes_).index(run.test_class)
    for shift in sorted({0.0, *shifts, *(-s for s in shifts)}) if shifts else ():
        class_evidence = path_class_evidence(scorer, tc.belief, obs, pos + np.array([shift / 100.0, 0.0, 0.0]), quat)
        margins[shift] = float(class_evidence[true_class] - np.delete(class_evidence, true_class).max())
    near = {
        a: evidence["truth"]
        - float(path_recognition(scorer, tc.belief, obs, pos, turned(quat, np.deg2rad(a)))[0].sum())
        for a in sorted({*turns, *(-t for t in turns)})
    }  # the truth's margin over the path turned by a
    first = int(np.argmax(obs.counts > 0))
    early = {a: (per_frame["truth"] - per_frame[a])[first:first + EARLY_FRAMES] for a in ALTERNATIVES}
    return {"key": run.key, "condition": run.condition_label, "class": run.test_class, **evidence,
            "recognised": recognised, "margins": margins, "early": early, "near": near,
            "causal": {group: causal_choice(per_frame, heading, names) for group, names in CAUSAL_GROUPS.items()},
            "motion": motion_so_far(obs)}


def motion_so_far(obs) -> np.ndarray:
    """``(T,)`` the motion the flows have shown up to each frame: the running sum of each frame's mean flow
    speed (px/s; 0 for a frame without flows)."""
    return np.cumsum([np.linalg.norm(f[:, 2:4], axis=1).mean() if len(f) else 0.0 for f in obs.flows])


#: The paths the causal chooser picks among (``causal_choice``): all, and the truth with only one kind of
#: alternative, so that the heading error a kind costs can be read apart.
CAUSAL_GROUPS = {"all": ("truth", *ALTERNATIVES), "turns": ("truth", "turn+90", "turn180", "turn-90"),
                 "twins": ("truth", "twin", "twin_upright")}


def causal_choice(per_frame: dict, heading: dict, names: tuple) -> dict:
    """The causal chooser that knows the true path and ``names``' alternatives exactly: at every frame it reports
    the path with the most evidence so far (``per_frame`` summed up to that frame; ``heading``: each path's
    heading error at every frame, deg). Returns its mean heading
    error over the clip (deg, as ``evaluate`` measures it), the heading error at ten instants (as
    ``metrics.heading_error_curve`` samples them), the share of frames at which it reports the truth, and the
    offline chooser's mean heading error (the path with the most evidence over the whole clip, reported at
    every frame: what an offline estimate choosing among the same paths would give). A
    tracker, which knows neither the positions nor which alternatives exist, chooses from the same evidence
    among inexact paths: its causal heading error is not expected below this."""
    total = np.cumsum(np.array([per_frame[n] for n in names]), axis=1)        # (paths, T)
    # Paths tied for the most evidence (every path before the first flows) are reported with equal chance:
    # each frame's error is the mean over the tied paths.
    tied = total >= total.max(axis=0) - 1e-9
    errors = np.array([heading[n] for n in names])
    error = (errors * tied).sum(axis=0) / tied.sum(axis=0)
    instants = np.round(np.linspace(0, len(error) - 1, CURVE_POINTS)).astype(int)
    final = tied[:, -1]
    return {"heading_deg": float(error.mean()), "curve": error[instants].tolist(), "per_frame": error,
            "truth_share": float(np.mean(tied[0] / tied.sum(axis=0))),
            "offline_heading_deg": float((errors.mean(axis=1) * final).sum() / final.sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap)
    ap.add_argument("--shifts", type=float, nargs="*", default=[],
                    help="sideways shifts (cm) of the true path at which every class is scored (module docstring)")
    ap.add_argument("--turns", type=float, nargs="*", default=[],
                    help="turns (deg, both ways) of the true path to score against it (module docstring)")
    args = ap.parse_args()
    runs = dev_runs.selected(args, pick=np.random.default_rng(0))
    t0 = time.perf_counter()
    rows = dev_runs.map_runs(partial(_one, shifts=tuple(args.shifts), turns=tuple(args.turns)), runs, args)
    print(f"{'run':28s} {'condition':24s} " + " ".join(f"{a:>9s}" for a in ALTERNATIVES) + "   (truth minus "
          "alternative, tempered nats)")
    for r in rows:
        print(f"{r['key']:28s} {r['condition']:24s} "
              + " ".join(f"{r['truth'] - r[a]:9.1f}" for a in ALTERNATIVES))
    print()
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        margin = np.array([[r["truth"] - r[a] for a in ALTERNATIVES] for r in sub])
        wins = (margin > 0).all(axis=1)
        per_alt = ", ".join(f"{a} {100 * np.mean(margin[:, i] > 0):.0f}%" for i, a in enumerate(ALTERNATIVES))
        print(f"{cond}: truth beats every alternative in {wins.sum()}/{len(sub)} runs ({100 * wins.mean():.0f}%); "
              f"per alternative: {per_alt}")
        print(f"  smallest margins: " + ", ".join(f"{a} {margin[:, i].min():.1f}" for i, a in enumerate(ALTERNATIVES))
              + f"; runs lost: {', '.join(sub[i]['key'] + ' (' + sub[i]['class'] + ')' for i in np.flatnonzero(~wins))}")
    print("\nrecognised (final class posterior along the path): truth / twin / upright twin")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]

        def share(runs, path):
            return f"{100 * np.mean([r['recognised'][path] for r in runs]):.0f}"

        per_class = {c: [r for r in sub if r["class"] == c] for c in sorted({r["class"] for r in sub})}
        print(f"{cond}: {share(sub, 'truth')}% / {share(sub, 'twin')}% / {share(sub, 'twin_upright')}%; "
              + ", ".join(f"{c} {share(rs, 'truth')}/{share(rs, 'twin')}/{share(rs, 'twin_upright')}%"
                          for c, rs in per_class.items()))
        misread = np.array([r["truth"] - r["twin"] for r in sub if not r["recognised"]["twin"]])
        if len(misread):
            print(f"  twins misread: {len(misread)}; the truth's evidence minus the twin's there: "
                  + ", ".join(f"{m:.0f}" for m in np.sort(misread)))
    print_causal(rows)
    print_early(rows)
    if args.shifts:
        print_margins(rows, sorted(args.shifts))
    if args.turns:
        print_near_turns(rows)
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s")


def print_causal(rows: list[dict]) -> None:
    """Per condition and group of alternatives, the causal chooser's heading error (``causal_choice``)."""
    print("\ncausal chooser among the exact paths (the most evidence so far, every frame): mean heading error over "
          "the clip (deg; mean and median over runs), its median at ten instants, frames reporting the truth")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        for group in CAUSAL_GROUPS:
            err = np.array([r["causal"][group]["heading_deg"] for r in sub])
            curve = np.median([r["causal"][group]["curve"] for r in sub], axis=0)
            share = np.mean([r["causal"][group]["truth_share"] for r in sub])
            offline = np.array([r["causal"][group]["offline_heading_deg"] for r in sub])
            print(f"{cond} {group:6s}: {err.mean():5.1f} (median {np.median(err):5.1f}); over the clip "
                  + " ".join(f"{v:.0f}" for v in curve) + f"; the truth at {100 * share:.0f}% of frames; "
                  f"offline {offline.mean():5.1f}")
        error = np.concatenate([r["causal"]["all"]["per_frame"] for r in sub])
        motion = np.concatenate([r["motion"] for r in sub])
        edges = np.percentile(motion, [0, 10, 30, 70, 100])
        bins = np.clip(np.searchsorted(edges, motion, side="right") - 1, 0, len(edges) - 2)
        first_fifth = np.concatenate([np.arange(len(r["motion"])) < 0.2 * len(r["motion"]) for r in sub])
        below = first_fifth & (motion <= np.median(motion[first_fifth]))
        print("  by the motion shown so far (all; frames in its 0-10, 10-30, 30-70, 70-100% quantiles): "
              + ", ".join(f"{error[bins == b].mean():.0f}" for b in range(len(edges) - 1))
              + f"; in each clip's first fifth, below its median motion {error[below].mean():.0f}, above "
              f"{error[first_fifth & ~below].mean():.0f}")
        per_class = {c: [r["causal"]["all"] for r in sub if r["class"] == c] for c in sorted({r["class"] for r in sub})}
        print("  per class (all; mean, and the median at the second and third instants): " + ", ".join(
            f"{c} {np.mean([x['heading_deg'] for x in xs]):.0f} ({np.median([x['curve'][1] for x in xs]):.0f}, "
            f"{np.median([x['curve'][2] for x in xs]):.0f})" for c, xs in per_class.items()))


def print_early(rows: list[dict]) -> None:
    """Per condition and alternative: how much each of the first frames with flows tells the truth from the
    alternative (its per-frame evidence minus the alternative's; median over runs, and the share of runs in which
    the frame favours the truth). Early in a clip the discrete primitives rest, and the chooser is wrong there."""
    print(f"\nthe first {EARLY_FRAMES} frames with flows: per-frame evidence of the truth minus the alternative's "
          "(tempered nats; median over runs), and the share of runs that frame favours the truth")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        print(f"{cond}:")
        for a in ALTERNATIVES:
            m = [r["early"][a] for r in sub]
            n = min(len(x) for x in m)
            m = np.array([x[:n] for x in m])
            print(f"  {a:12s} " + " ".join(f"{v:6.2f}" for v in np.median(m, axis=0)) + "   favours the truth "
                  + " ".join(f"{v:.2f}" for v in (m > 0).mean(axis=0)))


def print_margins(rows: list[dict], shifts: list[float]) -> None:
    """Per condition and class: the true class's margin over the best other class along the true path, and the
    runs whose lead another class takes within each sideways shift (``--shifts``)."""
    print("\nthe true class's margin over the best other class along the true path (nats), and runs where a "
          "sideways shift of at most " + ", ".join(f"{s:g}" for s in shifts) + " cm gives another class the lead")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        print(f"{cond}:")
        for c in sorted({r["class"] for r in sub}):
            runs = [r for r in sub if r["class"] == c]
            at_truth = np.array([r["margins"][0.0] for r in runs])
            turned = [sum(min(v for k, v in r["margins"].items() if abs(k) <= s) < 0 for r in runs) for s in shifts]
            print(f"  {c:13s} median {np.median(at_truth):7.1f}, smallest {at_truth.min():7.1f}; turned over: "
                  + ", ".join(f"{n}/{len(runs)}" for n in turned))


def print_near_turns(rows: list[dict]) -> None:
    """Per condition and class: the truth's evidence minus the path turned by each angle of ``--turns`` (median
    over runs), and the share of runs in which the truth beats every turned path."""
    angles = sorted(rows[0]["near"])
    print("\nthe true path against itself turned about the body's vertical (deg): the truth's evidence minus the "
          "turned path's (tempered nats over the clip, median over runs), and the runs where the truth beats them all")
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sub = [r for r in rows if r["condition"] == cond]
        print(f"{cond}:  " + " ".join(f"{a:+6.0f}" for a in angles))
        for c in sorted({r["class"] for r in sub}):
            margin = np.array([[r["near"][a] for a in angles] for r in sub if r["class"] == c])
            print(f"  {c:13s} " + " ".join(f"{v:6.1f}" for v in np.median(margin, axis=0))
                  + f"   truth best {(margin > 0).all(axis=1).sum()}/{len(margin)}")


if __name__ == "__main__":
    main()
