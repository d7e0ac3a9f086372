"""Runs per minute on a Dask cluster with 1 and 2 local workers, and the parallel efficiency (target >= 85 %).

    MUJOCO_GL=egl python benchmarks/dask_throughput.py [--scenario scenarios/ci.yaml] [--runs 12]

Each worker is one process with one thread (a run is single-threaded numpy and MuJoCo). The database is built
once before timing, and every worker does one warm-up run (imports, numba compilation, the engine's database
transform) before the clock starts, so the figure is the steady-state throughput. Efficiency is
``rpm(2) / (2 rpm(1))``; it needs two otherwise idle cores. Exits 1 below the target.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

from dask.distributed import Client, LocalCluster

from harness.evaluation import pipeline
from harness.evaluation.runner import plan, run_scenario
from harness.evaluation.loading import load_scenario

TARGET = 0.85


def _warm(run) -> int:
    pipeline.run_one(run)
    return 0


def runs_per_minute(scenario, workers: int, n_runs: int, root: Path) -> float:
    cache = root / "cache"
    first = plan(scenario, cache)[0]
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.run(_warm, first)
        start = time.perf_counter()
        run_scenario(scenario, root / f"w{workers}", pipeline.run_one, scheduler=cluster.scheduler_address,
                     limit=n_runs, cache_dir=cache, progress=False)
        elapsed = time.perf_counter() - start
    return 60.0 * n_runs / elapsed


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="scenarios/ci.yaml")
    p.add_argument("--runs", type=int, default=12, help="timed runs per cluster size")
    args = p.parse_args()
    scenario = load_scenario(args.scenario)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        planned = len(plan(scenario, root / "cache"))
        if args.runs > planned:     # the runner stops at the plan's end: a rate over args.runs would be inflated
            print(f"{args.scenario} plans {planned} runs: timing {planned}, not {args.runs}")
            args.runs = planned
        pipeline.database(scenario, None, root / "cache")      # procedural: one database for every run
        rpm = {n: runs_per_minute(scenario, n, args.runs, root) for n in (1, 2)}
    eff = rpm[2] / (2.0 * rpm[1])
    print(f"{args.scenario}, {args.runs} runs: 1 worker {rpm[1]:.1f} runs/min, 2 workers {rpm[2]:.1f} runs/min; "
          f"parallel efficiency {eff:.0%} (target >= {TARGET:.0%})")
    print("PASS" if eff >= TARGET else "FAIL")
    return 0 if eff >= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
