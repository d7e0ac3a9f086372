"""The runner: plan, seeds, journal, resume after SIGKILL, parallel execution, identical tables."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness.evaluation import runner
from harness.evaluation.cache import cached, path_for_key
from harness.evaluation.journal import ResultsError
from harness.evaluation.journal import read as read_journal
from harness.evaluation.loading import parse_scenario
from harness.evaluation.scenario import PROCEDURAL_CLASSES

from fakes import TINY, failing_run, fake_run, slow_fake_run  # noqa: E402


@pytest.fixture
def tiny():
    return parse_scenario(TINY, "tiny.yaml")


def test_plan_is_the_cartesian_product_with_distinct_deterministic_seeds(tiny, tmp_path):
    runs = runner.plan(tiny, tmp_path)
    assert len(runs) == 4 * 2 * 3                      # conditions x repeats x test motions
    assert [r.key for r in runs] == sorted(r.key for r in runs)
    assert len({r.key for r in runs}) == len(runs)
    conds = {(r.condition, r.config.markers.count, r.config.occluders.amount) for r in runs}
    assert conds == {(0, 10, 0.0), (1, 10, 0.3), (2, 30, 0.0), (3, 30, 0.3)}
    assert {r.test_demo for r in runs} == {8}          # held out: after the 8 training demos
    # Seeds: distinct across repeats and test motions, shared across conditions (common random numbers).
    by_cell = {}
    for r in runs:
        by_cell.setdefault((r.repeat, r.test_class, r.test_demo), set()).add(r.seed)
    assert all(len(s) == 1 for s in by_cell.values()) and len({next(iter(s)) for s in by_cell.values()}) == 6
    again = runner.plan(parse_scenario(TINY), tmp_path)
    assert [r.seed for r in again] == [r.seed for r in runs]
    expected = np.random.SeedSequence([5, 1, runner._word("run"), 8]).generate_state(2, np.uint32)
    assert runner.derive_seed(5, 1, "run", 8) == (int(expected[1]) << 32 | int(expected[0])) & (2**63 - 1)
    assert runner.derive_seed(6, 1, "run", 8) != runner.derive_seed(5, 1, "run", 8)


def test_rows_carry_identity_and_are_sorted(tiny, tmp_path):
    table = runner.run_scenario(tiny, tmp_path / "tiny", fake_run, progress=False)
    assert len(table) == 24 * 3
    for col in ("run_key", "scenario", "condition", "markers.count", "occluders.amount", "repeat",
                "test_class", "test_demo", "seed", "method", "correct"):
        assert col in table
    assert list(table["run_key"]) == sorted(table["run_key"])
    assert (tmp_path / "tiny" / "runs.csv").is_file()
    rows = pd.read_csv(tmp_path / "tiny" / "runs.csv")
    assert np.allclose(rows["mpjpe_cam_mm"], table["mpjpe_cam_mm"])


def test_parallel_equals_serial(tiny, tmp_path):
    a = runner.run_scenario(tiny, tmp_path / "a", fake_run, jobs=1, limit=6, progress=False)
    b = runner.run_scenario(tiny, tmp_path / "b", fake_run, jobs=2, limit=6, progress=False)
    pd.testing.assert_frame_equal(a, b)


def test_limit_then_resume_completes_without_repeats(tiny, tmp_path):
    calls = []

    def counting(run):
        calls.append(run.key)
        return fake_run(run)

    runner.run_scenario(tiny, tmp_path / "t", counting, limit=5, progress=False)
    full = runner.run_scenario(tiny, tmp_path / "t", counting, progress=False)
    assert len(calls) == 24 and len(set(calls)) == 24
    assert len(read_journal(tmp_path / "t" / "runs.jsonl")) == 24
    assert full["run_key"].nunique() == 24


def test_a_changed_scenario_is_refused_then_started_fresh(tiny, tmp_path):
    runner.run_scenario(tiny, tmp_path / "t", fake_run, limit=3, progress=False)
    changed = parse_scenario({**TINY, "seed": 6})
    with pytest.raises(ResultsError, match="different version of this scenario.*--fresh"):
        runner.run_scenario(changed, tmp_path / "t", fake_run, progress=False)
    table = runner.run_scenario(changed, tmp_path / "t", fake_run, limit=2, fresh=True, progress=False)
    assert table["run_key"].nunique() == 2
    assert list((tmp_path / "t").glob("runs.stale-*.jsonl"))


def test_a_failing_run_names_itself_and_keeps_finished_runs(tiny, tmp_path):
    with pytest.raises(runner.RunError, match="run c000/r001/run/d008 failed: kick exploded"):
        runner.run_scenario(tiny, tmp_path / "t", failing_run, progress=False)
    done = read_journal(tmp_path / "t" / "runs.jsonl")
    assert [r["key"] for r in done] == ["c000/r000/kick/d008", "c000/r000/run/d008", "c000/r000/walk/d008",
                                        "c000/r001/kick/d008"]


def test_torn_last_line_is_dropped(tiny, tmp_path):
    runner.run_scenario(tiny, tmp_path / "t", fake_run, limit=3, progress=False)
    path = tmp_path / "t" / "runs.jsonl"
    with open(path, "ab") as fh:
        fh.write(b'{"key": "c000/r000/walk/d008", "hash": "x", "ro')
    assert len(read_journal(path)) == 3
    assert path.read_bytes().endswith(b"\n")


_CHILD = """
import sys
sys.path.insert(0, {tests!r})
from harness.evaluation.runner import run_scenario
from harness.evaluation.loading import parse_scenario
import fakes
run_scenario(parse_scenario(fakes.TINY), {out!r}, fakes.slow_fake_run, progress=False)
"""


def test_sigkill_then_resume_equals_an_uninterrupted_run(tiny, tmp_path):
    out = tmp_path / "killed"
    code = _CHILD.format(tests=str(Path(__file__).parent), out=str(out))
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    rng = np.random.default_rng(11)
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, start_new_session=True)
    journal = out / "runs.jsonl"
    target = int(rng.integers(3, 15))
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None:
        if journal.exists() and journal.read_bytes().count(b"\n") >= target:
            break
        time.sleep(0.01)
    time.sleep(float(rng.uniform(0.0, 0.05)))            # land somewhere inside a run (or inside a write)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    partial = read_journal(journal, repair=False)
    assert 0 < len(partial) < 24, "the kill should interrupt the sweep"
    resumed = runner.run_scenario(tiny, out, fake_run, progress=False)
    reference = runner.run_scenario(tiny, tmp_path / "clean", fake_run, progress=False)
    pd.testing.assert_frame_equal(resumed, reference)
    keys = [r["key"] for r in read_journal(journal)]
    assert len(keys) == len(set(keys)) == 24


def test_cache_builds_once_and_loads_after(tmp_path):
    builds = []

    def build():
        builds.append(1)
        return np.arange(5.0)

    path = path_for_key(tmp_path, {"source": "procedural", "states": 20, "classes": list(PROCEDURAL_CLASSES)})
    assert path == path_for_key(tmp_path, {"states": 20, "classes": list(PROCEDURAL_CLASSES), "source": "procedural"})
    assert path != path_for_key(tmp_path, {"source": "procedural", "states": 21, "classes": list(PROCEDURAL_CLASSES)})
    save = lambda a, fh: np.save(fh, a)   # noqa: E731
    first = cached(path, build, save, np.load)
    second = cached(path, build, save, np.load)
    assert builds == [1] and np.array_equal(first, second)
    assert json.loads(path.with_suffix(".json").read_text())["states"] == 20


# --- issue 23: the main process killed with --jobs 2, a disk that fills up ----------------------------------

_EVALUATE = """
import sys
sys.path.insert(0, {tests!r})
if __name__ == "__main__":          # the spawned workers import this module again: they must not evaluate
    import fakes
    import harness.evaluation.pipeline as pipeline
    pipeline.run_one = fakes.slower_fake_run        # workers receive it by name (fakes.slower_fake_run)
    from harness.cli import main
    sys.exit(main(sys.argv[1:]))
"""


def _processes() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, state) of every process, from /proc."""
    out = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            out[int(entry)] = (int(fields[1]), fields[0])
    return out


def _descendants(pid: int) -> set[int]:
    table, found, frontier = _processes(), set(), [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, _) in table.items():
            if ppid == parent and child not in found:
                found.add(child)
                frontier.append(child)
    return found


def _alive(pids: set[int]) -> set[int]:
    table = _processes()
    return {p for p in pids if p in table and table[p][1] != "Z"}


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
def test_sigkill_of_evaluate_with_two_jobs_leaves_no_process_and_resumes(tiny, tmp_path):
    """`harness evaluate --jobs 2` killed with SIGKILL while runs are in flight: its workers and the resource
    tracker are gone within 5 s (they watch their parent), and the resumed journal's rows equal an
    uninterrupted run's."""
    script = tmp_path / "evaluate.py"
    script.write_text(_EVALUATE.format(tests=str(Path(__file__).parent)))
    scenario = tmp_path / "tiny.yaml"
    scenario.write_text(json.dumps(TINY))           # JSON is YAML
    results = tmp_path / "results"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen([sys.executable, str(script), "evaluate", str(scenario), "--results", str(results),
                             "--jobs", "2", "--quiet"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    journal = results / "tiny" / "runs.jsonl"
    children: set[int] = set()
    try:
        deadline = time.time() + 60
        while time.time() < deadline and proc.poll() is None:
            if journal.exists() and journal.read_bytes().count(b"\n") >= 2:
                break
            time.sleep(0.02)
        children = _descendants(proc.pid)
        assert len(children) >= 2, "the two workers should be running"
        proc.kill()
        proc.wait()
        killed_at = time.time()
        while _alive(children) and time.time() - killed_at < 5.0:
            time.sleep(0.05)
        assert not _alive(children), f"left running 5 s after the kill: {sorted(_alive(children))}"
    finally:
        for pid in _alive(children):         # only the processes this test started
            os.kill(pid, signal.SIGKILL)
    partial = read_journal(journal, repair=False)
    assert 0 < len(partial) < 24, "the kill should interrupt the sweep"
    resumed = runner.run_scenario(tiny, results / "tiny", fake_run, progress=False)
    reference = runner.run_scenario(tiny, tmp_path / "clean" / "tiny", fake_run, progress=False)
    pd.testing.assert_frame_equal(resumed, reference)
    assert len({r["key"] for r in read_journal(journal)}) == 24


def test_a_full_disk_stops_with_one_error_and_loses_no_recorded_run(tiny, tmp_path, monkeypatch):
    import errno

    from harness.evaluation import journal as journal_module

    real_fsync, calls = os.fsync, []

    def full(fd):
        calls.append(fd)
        if len(calls) == 4:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    monkeypatch.setattr(journal_module.os, "fsync", full)
    with pytest.raises(ResultsError, match=r"runs.jsonl: cannot record run .* \(No space left on device\); the runs "
                                           r"recorded before it are kept"):
        runner.run_scenario(tiny, tmp_path / "t", fake_run, progress=False)
    monkeypatch.setattr(journal_module.os, "fsync", real_fsync)
    assert len(read_journal(tmp_path / "t" / "runs.jsonl", repair=False)) >= 3
    resumed = runner.run_scenario(tiny, tmp_path / "t", fake_run, progress=False)
    pd.testing.assert_frame_equal(resumed, runner.run_scenario(tiny, tmp_path / "clean", fake_run, progress=False))


def test_a_refused_write_is_one_error_naming_the_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    import errno

    from harness import io

    def full(src, dst):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(io.os, "replace", full)
    with pytest.raises(io.FileWriteError, match=r"report.md: cannot write \(No space left on device\)"):
        io.write_text_atomic(tmp_path / "report.md", "text")
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    (tmp_path / "afile").write_text("x")
    with pytest.raises(io.FileWriteError, match="afile/report.md: cannot write"):
        io.write_text_atomic(tmp_path / "afile" / "report.md", "text")


def test_swept_repeats_run_per_condition_with_shared_seeds(tmp_path):
    s = parse_scenario({**{k: v for k, v in TINY.items() if k != "sweep"}, "sweep": {"repeats": [1, 3]}})
    runs = runner.plan(s, tmp_path)
    per = {c: sorted({r.repeat for r in runs if r.condition == c}) for c in (0, 1)}
    assert per == {0: [0], 1: [0, 1, 2]}
    seeds = {(r.condition, r.repeat, r.test_class): r.seed for r in runs}
    assert all(seeds[(0, 0, c)] == seeds[(1, 0, c)] for c in ("walk", "run", "kick"))     # repeat 0: shared
    assert len({seeds[(1, r, "walk")] for r in range(3)}) == 3


def test_a_first_evaluation_is_told_that_the_kernels_compile(tmp_path):
    """``compile_notice`` (printed by ``evaluate``, ``regress`` and ``rebaseline`` unless ``--quiet``): a cache
    directory without compiled kernels, missing or empty, gives the one-line notice naming it; once numba has
    written a kernel's index there, nothing."""
    from harness.evaluation.cli import compile_notice

    missing = tmp_path / "missing"
    assert "kernels are compiled on first use" in compile_notice(missing) and str(missing) in compile_notice(missing)
    (tmp_path / "cache" / "engine").mkdir(parents=True)
    assert compile_notice(tmp_path / "cache") is not None
    (tmp_path / "cache" / "engine" / "likelihood._densities-62.py311.nbi").write_bytes(b"")
    assert compile_notice(tmp_path / "cache") is None
