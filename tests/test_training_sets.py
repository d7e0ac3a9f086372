"""The training set is the database's cache key: for every split, the test motion never trains its own
database, and two runs whose training sets differ never share one (``pipeline.training_motions`` is the one
rule, ``pipeline.database_key`` is computed from what it returns)."""

import shutil

import numpy as np
import pytest

from conftest import require_mocap
from harness.evaluation import pipeline
from harness.evaluation.cache import stable_hash
from harness.evaluation.runner import plan
from harness.evaluation.loading import parse_scenario
from harness.evaluation.scenario_captures import resolve_capture

# Two subjects' walks, one subject's punches (two strikes of one take, the capture stream's take) and a run.
MANIFEST = ("file,format,skeleton,subject,trial,class,start,end,fps\n"
            "02_01.amc,amc,02.asf,2,1,walk,0,120,120\n02_01.amc,amc,02.asf,2,1,walk,120,240,120\n"
            "131_02.bvh,bvh,,131,2,walk,300,420,120\n02_05.amc,amc,02.asf,2,5,punch,94,260,120\n"
            "02_05.amc,amc,02.asf,2,5,punch,260,438,120\n09_01.bvh,bvh,,9,1,run,1,121,120\n")
PROCEDURAL = {"database": {"classes": ["walk", "punch", "run"], "train_demos": 2, "states": 4}}
SPLITS = {
    "heldout": PROCEDURAL | {"test": {"demos_per_class": 2}},
    "streams": PROCEDURAL | {"test": {"stream": {"count": 2, "primitives": [2, 2]}}},
    "captures": PROCEDURAL | {"test": {"split": "captures"}},
    "with_captures": {"database": PROCEDURAL["database"] | {"with_captures": True}, "test": {"split": "captures"}},
    "leave_one_out": {"database": {"source": "capture", "states": 4}, "test": {"split": "leave_one_out"}},
    "cross_subject": {"database": {"source": "capture", "states": 4}, "test": {"split": "cross_subject"}},
    "capture_stream": {"database": {"source": "capture", "states": 4},
                       "test": {"split": "leave_one_out", "stream": {"takes": ["02_05"]}}},
}


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    source = require_mocap()
    directory = tmp_path_factory.mktemp("captures")
    for name in ("02_01.amc", "02_05.amc", "02.asf", "131_02.bvh", "09_01.bvh"):
        shutil.copyfile(source / name, directory / name)       # links out of the directory are refused
    (directory / "MANIFEST.csv").write_text(MANIFEST)
    return directory


def _runs(split, capture_dir, tmp_path):
    scenario = resolve_capture(parse_scenario({"name": split, **SPLITS[split]}), capture_dir)
    return plan(scenario, tmp_path)


def _rows_of(motion):
    """Capture rows a motion covers: ``(file stem, frame)`` ranges from its demo id ``stem:start-end``."""
    stem, _, span = motion.demo.partition(":")
    start, end = map(int, span.split("-"))
    return stem, start, end


@pytest.mark.parametrize("split", list(SPLITS))
def test_the_test_motion_never_trains_its_own_database(split, capture_dir, tmp_path):
    pipeline.clear_caches()
    runs = _runs(split, capture_dir, tmp_path)
    keys, sets = {}, {}
    for run in runs:
        stream = pipeline.test_stream(run)
        test = pipeline.test_motion(run) if stream is None else stream.motion
        training = pipeline.training_motions(run.config, test)
        ids = [pipeline.training_identity(m) for m in training]
        assert training and pipeline.training_identity(test) not in ids
        capture = [m for m in training if m.source != "procedural"]
        if split in ("leave_one_out", "captures", "with_captures") and test.source != "procedural":
            assert all((m.label, m.demo) != (test.label, test.demo) for m in capture)
        if split in ("cross_subject", "with_captures"):
            assert all(m.subject != test.subject for m in capture)
        if split == "capture_stream":
            take = test.demo.split(":")[0]
            assert all(_rows_of(m)[0] != take for m in capture)
        if split == "leave_one_out":
            # No other row overlaps the test row's frames either.
            stem, start, end = _rows_of(test)
            assert not any(_rows_of(m)[0] == stem and _rows_of(m)[1] < end and start < _rows_of(m)[2]
                           for m in capture)
        keys[run.key] = stable_hash(pipeline.database_key(run.config, training))
        sets[run.key] = sorted(stable_hash(i) for i in ids)
    # One database per distinct training set, and never one for two different sets.
    for a in runs:
        for b in runs:
            assert (keys[a.key] == keys[b.key]) == (sets[a.key] == sets[b.key]), (a.key, b.key)
    distinct = len(set(keys.values()))
    if split in ("leave_one_out", "cross_subject"):
        assert distinct > 1                     # the splits do train different databases
    if split in ("heldout", "streams", "captures"):
        assert distinct == 1                    # ... and the procedural one is trained once


def test_a_changed_training_motion_changes_the_key(capture_dir, tmp_path):
    run = _runs("heldout", capture_dir, tmp_path)[0]
    training = pipeline.training_motions(run.config, None)
    key = pipeline.database_key(run.config, training)
    changed = list(training)
    changed[0] = changed[0].replace(qpos=changed[0].qpos + np.r_[np.zeros(7), np.full(50, 1e-9)])
    assert stable_hash(pipeline.database_key(run.config, changed)) != stable_hash(key)
    assert stable_hash(pipeline.database_key(run.config, training[:-1])) != stable_hash(key)
