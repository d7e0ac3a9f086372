"""Commands: ``evaluate``, ``export``, ``report``, ``compare``, ``regress``, ``rebaseline`` (registered with
``harness.cli.command``)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from harness.commands import command

DEFAULT_RESULTS = "results"
DEFAULT_CI = "scenarios/ci.yaml"
DEFAULT_BASELINE = "results/baseline"
MAX_JOBS = 256          # local worker processes; more is a typo (each holds a few hundred MB)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--results", default=DEFAULT_RESULTS, metavar="DIR",
                   help="results root; each scenario writes DIR/<name>/ (default: results)")
    p.add_argument("--mocap-dir", action="append", default=None, metavar="DIR",
                   help="a capture set's directory (repeatable; each named by its directory; default: "
                        "database.capture_dirs, $HARNESS_MOCAP_DIR, then the repository's capture library)")


def _running(p: argparse.ArgumentParser) -> None:
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="run on this Dask scheduler instead")
    p.add_argument("--fresh", action="store_true",
                   help="set aside runs stored under an older version of the scenario and start again")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _evaluate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario YAML file")
    _common(p)
    _running(p)
    p.add_argument("--limit", type=int, default=None, metavar="N", help="only the first N runs (smoke test)")


def _load(path: str, mocap_dir: str | None):
    from harness.evaluation.loading import load_scenario
    from harness.evaluation.scenario_captures import resolve_capture

    return resolve_capture(load_scenario(path), mocap_dir, where=path)


def _check_jobs(args) -> None:
    from harness.evaluation.runner import RunError

    if not 1 <= args.jobs <= MAX_JOBS:
        raise RunError(f"--jobs: must be in [1, {MAX_JOBS}], got {args.jobs}")


def compile_notice(cache_dir: str | Path | None = None) -> str | None:
    """What to tell a user before runs when ``cache_dir`` (default: ``NUMBA_CACHE_DIR``, which ``harness`` sets)
    holds no compiled kernel yet: each worker compiles the engine's kernels on first use, about a minute in which
    the progress bar stands still. None once a kernel's index is there. (This file does not name the compiler in
    lower case: ``harness.kernel_cache_dir`` versions the kernels by the files that do.)"""
    cache_dir = Path(os.environ["NUMBA_CACHE_DIR"] if cache_dir is None else cache_dir)
    if cache_dir.is_dir() and next(cache_dir.rglob("*.nbi"), None) is not None:
        return None
    return (f"the engine's kernels are compiled on first use, about a minute in each worker, once per version of "
            f"their sources (kept in {cache_dir})")


def _run(scenario, args, limit=None):
    from harness.evaluation.pipeline import run_one
    from harness.evaluation.report import make_report
    from harness.evaluation.runner import run_scenario

    _check_jobs(args)
    notice = None if args.quiet else compile_notice()
    if notice:
        print(notice, file=sys.stderr)
    out = Path(args.results) / scenario.name
    rows = run_scenario(scenario, out, run_one, jobs=args.jobs, scheduler=args.scheduler, limit=limit,
                        cache_dir=Path(args.results) / "cache", fresh=args.fresh, progress=not args.quiet)
    report = make_report(scenario, out, rows)
    print(f"{scenario.name}: {rows['run_key'].nunique() if len(rows) else 0} runs -> {report}")
    if "failed" in rows:
        from harness.evaluation.report import failed_rows

        failed = failed_rows(rows)
        if len(failed):
            print(f"{scenario.name}: {len(failed)} rows failed (method "
                  f"{', '.join(dict.fromkeys(failed['method']))}): listed in {report}", file=sys.stderr)
    return out


@command("evaluate", _evaluate_args)
def _evaluate(args: argparse.Namespace) -> int:
    """Run a scenario (resuming finished runs), then write its tables, plots and report."""
    _run(_load(args.scenario, args.mocap_dir), args, args.limit)
    return 0


def _export_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", required=True, metavar="DIR", help="the dataset's directory (resumes an export there)")
    _common(p)
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--fresh", action="store_true", help="set aside runs exported by an older version and start again")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--limit", type=int, default=None, metavar="N", help="only the first N runs")


@command("export", _export_args)
def _export(args: argparse.Namespace) -> int:
    """Write every run's observation, ground truth and metadata as files with an index (docs/export.md)."""
    from harness.evaluation.export import INDEX_NAME, export

    _check_jobs(args)
    scenario = _load(args.scenario, args.mocap_dir)
    index = export(scenario, args.out, Path(args.results) / "cache", jobs=args.jobs, limit=args.limit,
                   fresh=args.fresh, progress=not args.quiet)
    print(f"{scenario.name}: {len(index)} runs -> {Path(args.out) / INDEX_NAME}")
    return 0


def _report_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario YAML file")
    _common(p)


@command("report", _report_args)
def _report(args: argparse.Namespace) -> int:
    """Re-make a scenario's tables, plots and report from its stored runs."""
    from harness.evaluation.journal import ResultsError
    from harness.evaluation.report import make_report

    from harness.evaluation.results_dir import check

    scenario = _load(args.scenario, args.mocap_dir)
    out = Path(args.results) / scenario.name
    if not os.path.lexists(out / "runs.jsonl"):
        raise ResultsError(f"{out / 'runs.jsonl'}: no runs yet (run `harness evaluate {args.scenario}`)")
    check(out, Path(args.results) / "cache")
    print(make_report(scenario, out))
    return 0


def _compare_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("before", help="results of the first evaluation (A): a scenario's directory, or a results root")
    p.add_argument("after", help="results of the second evaluation (B) of the same scenario")
    p.add_argument("--out", default=None, metavar="FILE", help="also write the table as CSV")
    p.add_argument("--pool-scenarios", action="store_true",
                   help="the scenarios' runs together, condition by condition (copies of a scenario with other seeds)")


@command("compare", _compare_args)
def _compare(args: argparse.Namespace) -> int:
    """Compare two evaluations of the same runs, run by run: fixed and lost runs, paired differences."""
    from harness.evaluation.compare import compare, format_comparison, load_evaluation
    from harness.io import check_output_file, write_text_atomic

    out = None if args.out is None else check_output_file(args.out)
    table = compare(load_evaluation(args.before), load_evaluation(args.after), args.pool_scenarios)
    print(format_comparison(table))
    if out is not None:
        write_text_atomic(out, table.to_csv(index=False))
    return 0


def _regress_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=DEFAULT_CI, help=f"the CI scenario (default {DEFAULT_CI})")
    p.add_argument("--baseline", default=DEFAULT_BASELINE, metavar="DIR",
                   help=f"stored metrics and tolerances (default {DEFAULT_BASELINE})")
    _common(p)
    _running(p)
    p.add_argument("--no-run", action="store_true", help="compare the stored results without running")


@command("regress", _regress_args)
def _regress(args: argparse.Namespace) -> int:
    """Run the CI scenario and compare its metrics with the stored baseline; exit 1 on a regression."""
    from harness.evaluation import regress
    from harness.evaluation.scenario import scenario_hash

    scenario = _load(args.scenario, args.mocap_dir)
    out = Path(args.results) / scenario.name if args.no_run else _run(scenario, args)
    table, baseline = regress.check(out, args.baseline)
    if baseline.get("hash") not in (None, scenario_hash(scenario)):
        print(f"note: the baseline was stored for scenario hash {baseline.get('hash')}, the scenario is now "
              f"{scenario_hash(scenario)}", file=sys.stderr)
    print(regress.format_table(table))
    if regress.failed(table):
        bad = table[table["verdict"].isin(["REGRESSED", "MISSING"])]
        print(f"regression: {len(bad)} metric(s) outside tolerance: {', '.join(bad['metric'])}", file=sys.stderr)
        return 1
    print("no regression")
    return 0


@command("rebaseline", _regress_args)
def _rebaseline(args: argparse.Namespace) -> int:
    """Run the CI scenario and store its metrics as the new regression baseline (a deliberate act)."""
    from harness.evaluation import regress
    from harness.evaluation.scenario import scenario_hash

    scenario = _load(args.scenario, args.mocap_dir)
    out = Path(args.results) / scenario.name if args.no_run else _run(scenario, args)
    path = regress.rebaseline(out, args.baseline, scenario.name, scenario_hash(scenario))
    print(f"stored {path}")
    return 0
