"""Fit the class posterior's calibration (temperature, floor, the background class's bias) on development runs and
score it.

    MUJOCO_GL=egl python benchmarks/posterior_calibration.py [--seed 101 102] [--amount 0.0 0.4] [--limit N]
        [--jobs 2] [--rows rows.jsonl] [--check TEMPERATURE FLOOR] [--set SECTION.FIELD=VALUE ...]

Runs the engine (the ``full`` method) on a scenario's runs (default: the default scenario on development seed
101) and keeps each run's raw final log class posterior (``Estimate.raw_log_posterior``, before calibration)
and its true class (``unknown`` for an open-set run when the database has a background class). Fits
``(temperature, floor)``, and the bias of ``unknown`` when there is one, by the mean negative log-likelihood of the
true class (``harness.engine.confidence.fit``; every run must share one database's classes: a scenario of one
database, ``test.split: none``) and prints the calibration scores of ``harness.evaluation.calibration``
(ECE on equal-mass bins, Brier, NLL, share of wrong answers above 0.99) raw, under the engine's current
settings and under the fit, per condition and pooled. ``--check`` scores given values instead of fitting
(held-out runs: another seed). ``--rows`` keeps the per-run rows (appended as they finish, read back on a
rerun, so an interrupted run loses nothing).
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

import dev_runs


def _one(job) -> dict:
    run, overrides = job
    from harness.evaluation import pipeline

    inputs = pipeline.run_inputs(run)
    est = dev_runs.tracker_for(inputs, overrides).run(inputs.obs)
    classes = [str(c) for c in est.classes]
    label = run.test_class if run.test_class in classes or "unknown" not in classes else "unknown"
    return {"key": f"{run.seed}/{run.key}", "condition": run.condition_label, "class": label, "classes": classes,
            "log_posterior": [float(v) if np.isfinite(v) else -1e300 for v in est.raw_log_posterior[-1]]}


def _table(label: str, log_post: np.ndarray, true: np.ndarray, conditions: np.ndarray, tau: float, eps: float,
           bias: np.ndarray | None = None):
    from harness.engine.confidence import calibrated
    from harness.evaluation.calibration import scores

    shown = "" if bias is None else f", unknown bias {bias.max() + bias.min():.3g}"
    print(f"{label} (temperature {tau:.3g}, floor {eps:.3g}{shown}):")
    for cond in [*dict.fromkeys(conditions), None]:
        sel = conditions == cond if cond is not None else np.ones(len(true), bool)
        s = scores(calibrated(log_post[sel], tau, eps, bias), true[sel])
        print(f"  {cond or 'pooled':24s} runs {s['runs']:3d}  accuracy {s['accuracy']:.3f}  confidence "
              f"{s['confidence']:.3f}  ECE {s['ece']:.3f}  Brier {s['brier']:.3f}  NLL {s['nll']:.2f}  "
              f"wrong {s['wrong']:3d}  confident wrong {s['confident_wrong']:.2f}")


def main() -> None:
    from harness.engine import TrackerConfig
    from harness.engine.config import settings_from_strings
    from harness.engine.confidence import class_bias, fit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dev_runs.add_arguments(ap, seed=101)
    ap.add_argument("--rows", default=None, help="jsonl file of per-run rows (kept and reused)")
    ap.add_argument("--check", type=float, nargs="+", default=None, metavar="VALUE",
                    help="TEMPERATURE FLOOR [UNKNOWN_BIAS]: score these instead of fitting")
    args = ap.parse_args()
    runs = dev_runs.selected(args)
    overrides = settings_from_strings(args.set)
    done = {}
    if args.rows and Path(args.rows).exists():
        done = {r["key"]: r for r in map(json.loads, Path(args.rows).read_text().splitlines()) if r}
    todo = [r for r in runs if f"{r.seed}/{r.key}" not in done]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
        for i, row in enumerate(pool.map(_one, [(r, overrides) for r in todo])):
            done[row["key"]] = row
            if args.rows:
                with open(args.rows, "a") as f:
                    f.write(json.dumps(row) + "\n")
            print(f"\r{i + 1}/{len(todo)} runs, {time.perf_counter() - t0:.0f} s", end="", flush=True)
    print()
    rows = [done[f"{r.seed}/{r.key}"] for r in runs]
    classes = rows[0]["classes"]
    if any(r["classes"] != classes for r in rows):
        raise SystemExit("the runs have databases of other classes: calibrate on a scenario of one database")
    log_post = np.array([r["log_posterior"] for r in rows])
    true = np.array([classes.index(r["class"]) for r in rows])
    conditions = np.array([r["condition"] for r in rows])
    unknown = classes.index("unknown") if "unknown" in classes else None
    _table("raw", log_post, true, conditions, 1.0, 0.0)
    belief = TrackerConfig().with_values(overrides).belief
    _table("the engine's settings", log_post, true, conditions, belief.posterior_temperature, belief.posterior_floor,
           class_bias(classes, belief.unknown_bias))
    tau, eps, bias = (list(args.check) + [0.0])[:3] if args.check else fit(log_post, true, unknown)
    _table("checked" if args.check else "fitted", log_post, true, conditions, tau, eps, class_bias(classes, bias))


if __name__ == "__main__":
    main()
