"""The runs a development benchmark re-runs: a scenario's runs at some occlusion amounts, with its seed replaced
(development seeds for choices, the scenario's own for reporting) and at most some runs per condition."""

from __future__ import annotations

import argparse
import os

import numpy as np


def add_arguments(ap: argparse.ArgumentParser, seed: int | None = None) -> None:
    ap.add_argument("--scenario", default="scenarios/default.yaml")
    ap.add_argument("--seed", type=int, nargs="*", default=None if seed is None else [seed],
                    help="replace the scenario's seed (several: the runs of each)")
    ap.add_argument("--amount", type=float, nargs="*", default=[0.0, 0.4],
                    help="occlusion amounts (conditions of the scenario's occluders.amount sweep)")
    ap.add_argument("--limit", type=int, default=None, help="runs per condition")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cache", default="results/cache")
    ap.add_argument("--set", nargs="*", default=[], metavar="SECTION.FIELD=VALUE",
                    help="engine settings to use instead (e.g. tracks.particles=200)")
    ap.add_argument("--mocap-dir", default=os.environ.get("HARNESS_MOCAP_DIR", "../shared/mocap/cmu"),
                    help="capture directory, for capture scenarios")


def selected(args: argparse.Namespace, pick: np.random.Generator | None = None) -> list:
    """The planned runs ``args`` select (``add_arguments``); a run's ``seed`` tells runs of several seeds apart.
    With ``--limit``, the first runs of each condition, or with ``pick`` that many drawn from it (in key order)."""
    from harness.evaluation.runner import plan
    from harness.evaluation.loading import load_scenario
    from harness.evaluation.scenario_captures import resolve_capture

    os.environ["HARNESS_MOCAP_DIR"] = args.mocap_dir         # the workers resolve the capture set again
    scenario = resolve_capture(load_scenario(args.scenario), args.mocap_dir)
    seeded = [scenario.model_copy(update={"seed": s}) for s in args.seed] if args.seed else [scenario]
    runs = [r for sc in seeded for r in plan(sc, args.cache)
            if dict(r.swept).get("occluders.amount", r.config.occluders.amount) in args.amount]
    if args.limit:
        by_cond: dict = {}
        for r in runs:
            by_cond.setdefault((r.config.seed, r.condition), []).append(r)
        if pick is None:
            runs = [r for rs in by_cond.values() for r in rs[:args.limit]]
        else:
            runs = [r for rs in by_cond.values() for r in
                    sorted((rs[i] for i in pick.choice(len(rs), min(args.limit, len(rs)), replace=False)),
                           key=lambda r: r.key)]
    return runs


def map_runs(fn, runs: list, args: argparse.Namespace) -> list:
    """``fn((run, overrides))`` for every run, in order, in ``args.jobs`` spawned processes; ``overrides`` are the
    engine settings of ``--set``."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from harness.engine.config import settings_from_strings

    overrides = settings_from_strings(args.set)
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
        return list(pool.map(fn, [(r, overrides) for r in runs]))


def tracker_for(inputs, overrides: dict):
    """The run's tracker with engine ``overrides`` (``{section: {field: value}}``) applied: a new engine on the
    run's database when there are any (the model's points may change)."""
    from harness.engine import Tracker

    tracker = inputs.tracker()
    if not overrides:
        return tracker
    return Tracker(inputs.db, inputs.body, tracker.config.with_values(overrides), rng=tracker.rng)
