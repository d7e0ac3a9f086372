"""Runs under a cluster's memory limits: `evaluate`, resumed, and `report` under an address-space limit
(``ulimit -v``), and the reads that used to ask for their whole bound up front."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from harness.errors import HarnessError
from harness.evaluation import journal
from harness.io import read_input_bytes

ROOT = Path(__file__).resolve().parents[1]
# The limit. A tiny evaluation (MuJoCo, numba's kernels, a database, the engine) was measured at about
# 1.2 GB of address space; the journal's read asked for its 4 GiB bound before, and died at any limit below it.
LIMIT_BYTES = 3 * 10**9
SMALL = {"name": "small", "seed": 2, "database": {"classes": ["walk", "kick"], "train_demos": 2, "states": 4},
         "test": {"demos_per_class": 1}, "markers": {"count": 30}, "methods": ["full", "joint_space"],
         "engine": {"tracks": {"particles": 30}, "model": {"points": 30}}}

_LIMITED = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))
from harness.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _harness_limited(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    script = tmp_path / "limited.py"
    script.write_text(_LIMITED.format(limit=LIMIT_BYTES))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    return subprocess.run([sys.executable, str(script), *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=900)


def _rows(results: Path) -> pd.DataFrame:
    return pd.read_csv(results / "small" / "runs.csv").drop(columns=["ms_per_frame"])


def test_evaluate_resumed_and_report_run_under_a_3_gb_address_space_limit(tmp_path):
    scenario = tmp_path / "small.yaml"
    scenario.write_text(json.dumps(SMALL))             # JSON is YAML
    first, second = tmp_path / "a", tmp_path / "b"
    for args in (["--limit", "1"], []):                 # one run, then resumed: the journal is read back
        done = _harness_limited(tmp_path, "evaluate", str(scenario), "--results", str(first), "--quiet", *args)
        assert done.returncode == 0, done.stderr[-2000:]
        assert "MemoryError" not in done.stderr
    done = _harness_limited(tmp_path, "evaluate", str(scenario), "--results", str(second), "--quiet")
    assert done.returncode == 0, done.stderr[-2000:]
    report = _harness_limited(tmp_path, "report", str(scenario), "--results", str(first))
    assert report.returncode == 0, report.stderr[-2000:]
    a, b = _rows(first), _rows(second)
    assert a["run_key"].nunique() == 2
    pd.testing.assert_frame_equal(a, b)


_READ_UNDER_LIMIT = """
import resource, sys
from harness.evaluation import journal
resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))
print(len(journal.read(sys.argv[1])))
"""


def test_a_small_journal_is_read_under_a_limit_below_its_bound(tmp_path):
    """The journal's bound (4 GiB) is above the limit; a read sized by the bound fails at once, one sized by
    the file does not."""
    path = tmp_path / "runs.jsonl"
    path.write_text("".join(json.dumps({"key": f"c000/r000/walk/d{i:03d}", "hash": "h", "rows": [{"method": "full"}]})
                            + "\n" for i in range(3)))
    script = tmp_path / "read.py"
    script.write_text(_READ_UNDER_LIMIT.format(limit=LIMIT_BYTES))
    done = subprocess.run([sys.executable, str(script), str(path)], env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "3"
    assert journal.MAX_JOURNAL_BYTES > LIMIT_BYTES        # else this test would not test the bound


def test_a_file_that_grows_while_it_is_read_is_still_bounded(tmp_path, monkeypatch):
    """Sized by the file, the read still refuses a file that grew past the bound after it was measured, and
    reads the whole of one that grew within it."""
    import harness.io as io

    path = tmp_path / "f.txt"
    path.write_bytes(b"x" * 10)
    real = io.check_input_file

    def measured_then_grown(p, error, kind, max_bytes, extra=b"y" * 30):
        size = real(p, error, kind, max_bytes)
        with open(p, "ab") as fh:
            fh.write(extra)
        return size

    monkeypatch.setattr(io, "check_input_file", measured_then_grown)
    monkeypatch.setattr(io, "READ_CHUNK_BYTES", 7)
    with pytest.raises(HarnessError, match="too large for a test file \\(at most 20 bytes\\)"):
        read_input_bytes(path, HarnessError, "test", 20)
    path.write_bytes(b"x" * 10)
    assert read_input_bytes(path, HarnessError, "test", 100) == b"x" * 10 + b"y" * 30


def test_the_journal_is_streamed_one_line_at_a_time(tmp_path, monkeypatch):
    """A line longer than a record can be is refused naming it (the journal is read by lines, never whole),
    and a journal is not modified by a refused read."""
    monkeypatch.setattr(journal, "MAX_LINE_BYTES", 200)
    path = tmp_path / "runs.jsonl"
    good = json.dumps({"key": "c000/r000/walk/d000", "hash": "h", "rows": []}) + "\n"
    content = (good + json.dumps({"key": "c000/r000/walk/d001", "hash": "h", "rows": [{"x": "a" * 300}]}) + "\n"
               + '{"torn')
    path.write_text(content)
    with pytest.raises(journal.ResultsError, match=r"line 2: longer than 200 bytes"):
        journal.read(path)
    assert path.read_text() == content
    path.write_text(good + '{"torn')
    assert [r["key"] for r in journal.records(path)] == ["c000/r000/walk/d000"]
    assert path.read_text() == good                    # the torn line cut once every line was read

