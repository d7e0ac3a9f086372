"""The runner: a scenario becomes runs (conditions x repeats x test motions), executed in parallel, journaled.

Each run is identified by its *run key* ``c<condition>/r<repeat>/<class>/d<demo>`` (zero-padded, so the keys
sort in plan order within a class) and gets a seed derived with ``numpy.random.SeedSequence`` from the scenario
seed, the repeat, the test class and the test demo. The condition is deliberately *not* part of the seed:
every condition of a sweep sees the same marker placements, noise draws and particle initialisations (common
random numbers), so differences between conditions come from the swept value and paired comparisons are tight.

Finished runs are appended to ``runs.jsonl`` (see ``journal``) as they complete, in whatever order; the
table returned (and written as ``runs.csv``) is sorted by run key, so it does not depend on completion order or
on how many times the sweep was interrupted and resumed.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from harness.errors import HarnessError
from harness.evaluation.journal import Journal
from harness.evaluation.journal import records as journal_records
from harness.evaluation.results_dir import check as check_results_dir
from harness.evaluation.scenario import MAX_RUNS, Scenario, scenario_hash
from harness.evaluation.sweep import conditions
from harness.io import write_text_atomic
from harness.version import code_version

RunFunction = Callable[["RunSpec"], list[dict]]
IDENTITY_COLUMNS = ("run_key", "scenario", "condition", "repeat", "source", "test_class", "test_demo", "seed")
PROCEDURAL = "procedural"      # the source of a procedural test motion (a capture row's is its set's name)
STREAM_CLASS = "stream"         # the test class of a stream run (its labels are per frame)
SCHEDULER_TIMEOUT_S = 10.0      # a Dask scheduler that does not answer in this time is not there


class RunError(HarnessError):
    """A run function failed or returned something that is not one row per method."""


@dataclass(frozen=True)
class RunSpec:
    """Everything one run needs. ``config`` is the condition's resolved scenario (swept values applied).

    swept: the condition's ``(dotted key, value)`` pairs. test_source: ``procedural`` or the capture set of the
    test row. test_demo: the performer's demo index (procedural: held out, ``train_demos + i``) or the row's
    position among its set's rows of its class (``capture_splits.row_index``).
    seed: the run's seed (non-negative int below 2**63). cache_dir: where the pipeline caches databases.
    code: the code version the run was planned with (``harness.version``; a worker running other code
    refuses the run).
    """

    config: Scenario
    condition: int
    condition_label: str
    swept: tuple[tuple[str, Any], ...]
    repeat: int
    test_class: str
    test_demo: int
    seed: int
    cache_dir: str
    code: str = ""
    test_source: str = PROCEDURAL

    @property
    def key(self) -> str:
        return run_key(self.condition, self.repeat, self.test_class, self.test_demo, self.test_source)

    def rng(self) -> np.random.Generator:
        """The run's generator (a fresh one on every call, so that repeated calls are identical)."""
        return np.random.default_rng(self.seed)

    def identity(self) -> dict[str, Any]:
        """The identity columns the runner adds to each of the run's rows, swept keys included."""
        out = {"run_key": self.key, "scenario": self.config.name, "condition": self.condition_label}
        out.update({k: (v if isinstance(v, (int, float, str, bool)) else str(v)) for k, v in self.swept})
        out.update({"repeat": self.repeat, "source": self.test_source, "test_class": self.test_class,
                    "test_demo": self.test_demo, "seed": self.seed})
        return out


def run_key(condition: int, repeat: int, test_class: str, test_demo: int, source: str = PROCEDURAL) -> str:
    """``c000/r001/kick/d009``; a capture row's names its set: ``c000/r001/cmu/kick/d003``."""
    where = "" if source == PROCEDURAL else f"{source}/"
    return f"c{condition:03d}/r{repeat:03d}/{where}{test_class}/d{test_demo:03d}"


def _word(text: str) -> int:
    """A 32-bit integer from a string, stable across processes and Python versions (unlike ``hash``)."""
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")


def derive_seed(scenario_seed: int, repeat: int, test_class: str, test_demo: int, source: str = PROCEDURAL) -> int:
    """The run's seed: ``SeedSequence([scenario seed, repeat, word(class), demo])`` folded to 63 bits, with
    ``word(source)`` appended for a capture row (so rows of several sets never share draws)."""
    parts = [int(scenario_seed), int(repeat), _word(test_class), int(test_demo)]
    ss = np.random.SeedSequence(parts + ([] if source == PROCEDURAL else [_word(source)]))
    lo, hi = ss.generate_state(2, np.uint32)
    return int((int(hi) << 32 | int(lo)) & (2**63 - 1))


def motions_under_test(config: Scenario) -> list[tuple[str, str, int]]:
    """``(source, class, demo index)`` of every test motion: held-out procedural demos, and the capture rows the
    split tests (``capture_splits.verdicts``: known classes and open-set rows); for streams
    ``("procedural", "stream", i)`` or ``(set, "stream", i)``, the i-th procedural stream or capture take."""
    db, test = config.database, config.test
    if test.stream is not None:
        # Streams: one run per procedural stream or capture take; the class column says "stream".
        stream = test.stream
        if stream.takes is None:
            return [(PROCEDURAL, STREAM_CLASS, i) for i in range(stream.count)]
        return [(db.capture_sets[0], STREAM_CLASS, i) for i in range(len(stream.takes))]
    out = []
    if test.procedural:
        out += [(PROCEDURAL, c, db.train_demos + i) for c in config.classes for i in range(test.demos_per_class)]
    if test.captures:
        from harness.evaluation.capture_splits import verdicts

        if db.capture_dirs is None:
            raise RunError(f"{config.name}: capture scenario not resolved (call scenario_captures.resolve_capture "
                           f"first)")
        out += [(v.row.set_name, v.row.label, v.demo) for v in verdicts(config) if v.kind != "skipped"]
    return out


def plan(scenario: Scenario, cache_dir: str | Path) -> list[RunSpec]:
    """Every run of a scenario, sorted by run key (at most ``MAX_RUNS``)."""
    runs = []
    code = code_version()
    for cond in conditions(scenario):
        motions = motions_under_test(cond.config)
        repeats = cond.config.repeats       # swept repeats: each condition runs its own number
        capture_repeats = cond.config.test.capture_repeats or repeats
        if len(runs) + max(repeats, capture_repeats) * len(motions) > MAX_RUNS:
            raise RunError(f"{scenario.name}: the plan has more than {MAX_RUNS} runs: reduce repeats or the sweep")
        for source, cls, demo in motions:
            for rep in range(repeats if source == PROCEDURAL else capture_repeats):
                runs.append(RunSpec(cond.config, cond.index, cond.label, cond.values, rep, cls, demo,
                                    derive_seed(scenario.seed, rep, cls, demo, source), str(cache_dir), code,
                                    source))
    return sorted(runs, key=lambda r: r.key)


def _checked_rows(run: RunSpec, rows: Any) -> list[dict]:
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) and "method" in r for r in rows):
        raise RunError(f"run {run.key}: the run function must return a non-empty list of dicts with a "
                       f"'method' key, got {type(rows).__name__}")
    identity = run.identity()
    return [identity | row for row in rows]


def _execute_local(todo: list[RunSpec], run_fn: RunFunction, jobs: int) -> Iterable[tuple[RunSpec, Any]]:
    if jobs <= 1:
        for run in todo:
            yield run, _call(run_fn, run)
        return
    # spawn, not fork: MuJoCo, EGL and numba threads in the parent do not survive a fork reliably. Each worker
    # watches its parent (``_watch_parent``): a pool whose parent was killed (SIGKILL leaves it no chance to
    # shut the pool down) would otherwise wait on its queue forever, holding hundreds of MB per worker.
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_watch_parent,
                             initargs=(os.getpid(),)) as pool:
        pending = {pool.submit(run_fn, run): run for run in todo}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in sorted(done, key=lambda f: pending[f].key):
                    run = pending.pop(fut)
                    yield run, _call(lambda _: fut.result(), run)
        finally:
            for fut in pending:
                fut.cancel()


def connect(address: str, timeout_s: float | None = None):
    """A Dask client of the scheduler at ``address``; ``RunError`` (one line) when dask is missing or the
    scheduler does not answer within ``timeout_s`` (default ``SCHEDULER_TIMEOUT_S``). Called before the journal
    is opened, so a wrong address writes nothing."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise RunError(f"--scheduler {address}: dask.distributed is not installed "
                       f"(pip install 'monocular-motion-harness[dask]')") from None
    timeout = SCHEDULER_TIMEOUT_S if timeout_s is None else timeout_s
    try:
        return Client(address, timeout=f"{timeout}s")
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        why = " ".join(str(exc).split())[:160] or type(exc).__name__
        raise RunError(f"--scheduler {address}: no scheduler answered within {timeout:g} s ({why})") from None


PARENT_POLL_S = 0.5     # how often a worker looks for its parent (a killed run's workers exit within this)


def _watch_parent(parent: int) -> None:
    """In a worker: a daemon thread that ends the process as soon as its parent ``parent`` (pid) is gone.

    A process whose parent dies is re-parented (to init or a subreaper), so ``os.getppid`` changes; the
    check runs while a run computes too (numpy and the engine's kernels release the interpreter's lock often),
    so the worker exits within about ``PARENT_POLL_S`` of the parent's death, mid-run or idle. The journal is
    written by the parent only, so nothing a worker holds is lost: its run is done again on resume."""
    def watch():
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="watch-parent", daemon=True).start()


def _execute_dask(todo: list[RunSpec], run_fn: RunFunction, client) -> Iterable[tuple[RunSpec, Any]]:
    from dask.distributed import as_completed

    futures = {client.submit(run_fn, run, key=f"run-{run.key}-{run.seed}", pure=False): run for run in todo}
    for fut in as_completed(list(futures)):
        yield futures[fut], _call(lambda _: fut.result(), futures[fut])


def run_scenario(scenario: Scenario, results_dir: str | Path, run_fn: RunFunction, jobs: int = 1,
                 scheduler: str | None = None, limit: int | None = None, cache_dir: str | Path | None = None,
                 fresh: bool = False, progress: bool = True) -> pd.DataFrame:
    """Run every run of ``scenario`` not yet in ``results_dir/runs.jsonl``; return all rows sorted by run key.

    run_fn: ``run_fn(RunSpec) -> rows`` (``harness.evaluation.pipeline.run_one`` for a real evaluation; it must
    be importable by worker processes). results_dir: this scenario's directory (``results/<name>``). limit: only the first N runs of the plan
    (a smoke test; later calls without it complete the rest). cache_dir: database cache (default
    ``results_dir/../cache``, shared between scenarios). fresh: set aside runs of an older scenario version.
    Also writes ``scenario.json`` (resolved scenario and hash) and the sorted ``runs.csv``.
    """
    results_dir = Path(results_dir)
    cache_dir = Path(cache_dir) if cache_dir is not None else results_dir.parent / "cache"
    check_results_dir(results_dir, cache_dir)
    digest = scenario_hash(scenario)
    runs = plan(scenario, cache_dir)
    if limit is not None:
        runs = runs[:max(0, int(limit))]
    with contextlib.ExitStack() as stack:
        client = stack.enter_context(connect(scheduler)) if scheduler else None
        journal = stack.enter_context(Journal(results_dir, digest, fresh=fresh))
        write_text_atomic(results_dir / "scenario.json", _scenario_json(scenario, digest))
        todo = [r for r in runs if r.key not in journal]
        if todo:
            from harness.evaluation.progress import progress as progress_bar

            finished = (_execute_dask(todo, run_fn, client) if client is not None
                        else _execute_local(todo, run_fn, jobs))
            bar = progress_bar(len(todo), scenario.name, enabled=progress)     # a live bar on a terminal only
            try:
                for run, rows in finished:
                    journal.append(run.key, _checked_rows(run, rows))
                    bar.update(1)
            finally:
                bar.close()
    table = load_rows(results_dir, digest)
    write_text_atomic(results_dir / "runs.csv", table.to_csv(index=False))
    return table


def _call(fn: Callable[[RunSpec], Any], run: RunSpec) -> Any:
    """``fn(run)``, with a ``HarnessError`` re-raised as ``RunError`` naming the run (finished runs stay in the
    journal); any other exception is a bug and keeps its traceback, with a note naming the run."""
    try:
        return fn(run)
    except HarnessError as exc:
        raise RunError(f"run {run.key} failed: {exc} (finished runs are kept; re-run to resume)") from exc
    except Exception as exc:
        exc.add_note(f"in run {run.key} (seed {run.seed}); finished runs are kept")
        raise


def _scenario_json(scenario: Scenario, digest: str) -> str:
    import json

    return json.dumps({"hash": digest, "scenario": scenario.model_dump(mode="json")}, indent=2, sort_keys=True) + "\n"


def load_rows(results_dir: str | Path, digest: str | None = None) -> pd.DataFrame:
    """The journal's rows as one table sorted by run key then method (rows of other hashes left out)."""
    # Streamed: only the rows kept are held (a record's first occurrence of its key, as ``Journal`` counts it).
    kept: dict[str, list[dict]] = {}
    for rec in journal_records(Path(results_dir) / "runs.jsonl", repair=False):
        if (digest is None or rec["hash"] == digest) and rec["key"] not in kept:
            kept[rec["key"]] = rec["rows"]
    table = pd.DataFrame([row for key in sorted(kept) for row in kept[key]])
    if len(table):
        table = table.sort_values(["run_key", "method"], kind="stable").reset_index(drop=True)
    return table
