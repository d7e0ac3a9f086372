"""The training set is the database's cache key: for every split, the test motion and its held-out group never
train its own database, and two runs whose training sets differ never share one (``pipeline.training_motions``
is the one rule, ``pipeline.database_key`` is computed from what it returns, ``training_identity`` covers the
capture set and the style)."""

import shutil

import numpy as np
import pytest

from conftest import require_mocap
from harness.evaluation import pipeline
from harness.evaluation.cache import stable_hash
from harness.evaluation.capture_splits import group, verdicts
from harness.evaluation.loading import parse_scenario
from harness.evaluation.runner import plan
from harness.evaluation.scenario_captures import resolve_capture

# Set "cmu": two subjects' walks (styles given by hand), one subject's punches (two strikes of one take, the
# capture stream's take) and a run. Set "studio": another skeleton (its rows name a joint mapping), two styles
# of walks and runs, and a row of no primitive.
CMU = ("file,format,skeleton,subject,trial,class,start,end,fps,style\n"
       "02_01.amc,amc,02.asf,2,1,walk,0,120,120,calm\n02_01.amc,amc,02.asf,2,1,walk,120,240,120,brisk\n"
       "131_02.bvh,bvh,,131,2,walk,300,420,120,calm\n02_05.amc,amc,02.asf,2,5,punch,94,260,120,\n"
       "02_05.amc,amc,02.asf,2,5,punch,260,438,120,\n09_01.bvh,bvh,,9,1,run,1,121,120,brisk\n")
STUDIO = ("file,format,skeleton,subject,trial,class,start,end,fps,style\n"
          "dataset-1_walk_normal_002.bvh,bvh,mapping.yaml,b1,walk-normal-002,walk,0,31,30,normal\n"
          "dataset-1_walk_tired_001.bvh,bvh,mapping.yaml,b1,walk-tired-001,walk,0,40,30,tired\n"
          "dataset-1_run_tired_001.bvh,bvh,mapping.yaml,b1,run-tired-001,run,0,40,30,tired\n"
          "dataset-2_raise-up-both-hands_active_001.bvh,bvh,mapping.yaml,b2,raise-active-001,other,0,38,30,active\n")
CLASSES = ["walk", "punch", "run"]
PROCEDURAL = {"database": {"classes": CLASSES, "train_demos": 2, "states": 4}}
CAPTURES = {"source": "captures", "states": 4, "classes": CLASSES}
SPLITS = {
    "procedural": PROCEDURAL | {"test": {"demos_per_class": 2}},
    "streams": PROCEDURAL | {"test": {"stream": {"count": 2, "primitives": [2, 2]}}},
    "sim2real": PROCEDURAL | {"test": {"motions": "captures"}},
    "both_by_subject": {"database": PROCEDURAL["database"] | {"source": "both"},
                        "test": {"motions": "both", "demos_per_class": 1, "split": "subject"}},
    "row": {"database": CAPTURES, "test": {"motions": "captures", "split": "row"}},
    "subject": {"database": CAPTURES, "test": {"motions": "captures", "split": "subject"}},
    "style": {"database": CAPTURES, "test": {"motions": "captures", "split": "style"}},
    "source": {"database": CAPTURES | {"source": "both", "train_demos": 2},
               "test": {"motions": "captures", "split": "source"}},
    "none": {"database": CAPTURES, "test": {"motions": "captures", "split": "none"}},
    "capture_stream": {"database": CAPTURES, "database_sets": ["cmu"],
                       "test": {"motions": "captures", "split": "row", "stream": {"takes": ["02_05"]}}},
}


@pytest.fixture(scope="module")
def capture_dirs(tmp_path_factory):
    cmu = require_mocap()
    bandai = cmu.parent / "bandai"
    if not bandai.is_dir():
        pytest.skip(f"{bandai} is absent (the Bandai Namco sample captures, ../shared/mocap/bandai)")
    root = tmp_path_factory.mktemp("sets")
    out = []
    for name, source, files, manifest in (
            ("cmu", cmu, ("02_01.amc", "02_05.amc", "02.asf", "131_02.bvh", "09_01.bvh"), CMU),
            ("studio", bandai, ("dataset-1_walk_normal_002.bvh", "dataset-1_walk_tired_001.bvh",
                                "dataset-1_run_tired_001.bvh", "dataset-2_raise-up-both-hands_active_001.bvh",
                                "mapping.yaml"), STUDIO)):
        directory = root / name
        directory.mkdir()
        for f in files:
            shutil.copyfile(source / f, directory / f)       # links out of the directory are refused
        (directory / "MANIFEST.csv").write_text(manifest)
        out.append(directory)
    return out


def _runs(split, capture_dirs, tmp_path):
    raw = {k: v for k, v in SPLITS[split].items() if k != "database_sets"}
    dirs = capture_dirs[:1] if "database_sets" in SPLITS[split] else capture_dirs
    scenario = resolve_capture(parse_scenario({"name": split, **raw}), [str(d) for d in dirs])
    return plan(scenario, tmp_path)


def _rows_of(motion):
    """Capture rows a motion covers: ``(file stem, frame)`` ranges from its demo id ``stem:start-end``."""
    stem, _, span = motion.demo.partition(":")
    start, end = map(int, span.split("-"))
    return stem, start, end


@pytest.mark.parametrize("split", list(SPLITS))
def test_the_test_motion_and_its_group_never_train_its_own_database(split, capture_dirs, tmp_path):
    pipeline.clear_caches()
    runs = _runs(split, capture_dirs, tmp_path)
    assert runs
    keys, sets = {}, {}
    for run in runs:
        stream = pipeline.test_stream(run)
        test = pipeline.test_motion(run) if stream is None else stream.motion
        assert stream is not None or test.source == run.test_source
        training = pipeline.training_motions(run.config, test)
        ids = [pipeline.training_identity(m) for m in training]
        assert training and all(m.label != "other" for m in training)
        if split != "none":
            assert pipeline.training_identity(test) not in ids
        capture = [m for m in training if m.source != "procedural"]
        if test.source != "procedural" and split in ("row", "subject", "style", "source", "both_by_subject"):
            kind = "subject" if split == "both_by_subject" else split
            held = group(test.source, test.subject, test.style, test.demo, kind)
            assert held is not None
            assert all(group(m.source, m.subject, m.style, m.demo, kind) != held for m in capture), (run.key, kind)
        if split == "row" and test.source != "procedural":
            # No other row overlaps the test row's frames either.
            stem, start, end = _rows_of(test)
            assert not any(m.source == test.source and _rows_of(m)[0] == stem and _rows_of(m)[1] < end
                           and start < _rows_of(m)[2] for m in capture)
        if split == "capture_stream":
            take = test.demo.split(":")[0]
            assert all(_rows_of(m)[0] != take for m in capture)
        keys[run.key] = stable_hash(pipeline.database_key(run.config, training))
        sets[run.key] = sorted(stable_hash(i) for i in ids)
    # One database per distinct training set, and never one for two different sets.
    for a in runs:
        for b in runs:
            assert (keys[a.key] == keys[b.key]) == (sets[a.key] == sets[b.key]), (a.key, b.key)
    distinct = len(set(keys.values()))
    if split in ("row", "subject", "style", "source"):
        assert distinct > 1                     # the splits do train different databases
    if split in ("procedural", "streams", "sim2real", "none"):
        assert distinct == 1                    # ... and the others one each


def test_rows_are_tested_open_set_or_skipped_by_the_split(capture_dirs):
    """Under ``style`` the rows without a style only train; under ``source`` with captures alone a set whose
    classes no other set has is not testable; ``other`` is an open-set row."""
    def kinds(split, database=CAPTURES):
        s = resolve_capture(parse_scenario({"name": "v", "database": database,
                                            "test": {"motions": "captures", "split": split}}),
                            [str(d) for d in capture_dirs])
        return {(v.row.set_name, v.row.demo): (v.kind, v.why) for v in verdicts(s)}

    style = kinds("style")
    assert style[("cmu", "02_05:94-260")] == ("skipped", "no style")
    assert style[("cmu", "02_01:0-120")][0] == "tested"
    assert style[("studio", "dataset-2_raise-up-both-hands_active_001:0-38")][0] == "open_set"
    source = kinds("source")
    assert source[("cmu", "02_05:94-260")] == ("skipped", "no training row of punch outside its source")
    assert source[("cmu", "09_01:1-121")][0] == "tested"            # the studio has runs
    assert kinds("source", CAPTURES | {"source": "both"})[("cmu", "02_05:94-260")][0] == "tested"


def test_the_training_key_covers_the_set_and_the_style(capture_dirs, tmp_path):
    run = _runs("none", capture_dirs, tmp_path)[0]
    training = pipeline.training_motions(run.config, None)
    key = stable_hash(pipeline.database_key(run.config, training))
    for change in ({"style": "other-style"}, {"source": "another-set"}):
        changed = [training[0].replace(**change)] + list(training[1:])
        assert stable_hash(pipeline.database_key(run.config, changed)) != key, change


def test_a_changed_training_motion_changes_the_key(capture_dirs, tmp_path):
    run = _runs("procedural", capture_dirs, tmp_path)[0]
    training = pipeline.training_motions(run.config, None)
    key = pipeline.database_key(run.config, training)
    changed = list(training)
    changed[0] = changed[0].replace(qpos=changed[0].qpos + np.r_[np.zeros(7), np.full(50, 1e-9)])
    assert stable_hash(pipeline.database_key(run.config, changed)) != stable_hash(key)
    assert stable_hash(pipeline.database_key(run.config, training[:-1])) != stable_hash(key)


def test_the_database_learns_only_the_rows_its_select_lets_it(capture_dirs, tmp_path):
    """``database.select``: a database of procedural demonstrations and the studio's ``normal`` rows alone,
    whatever the tested row."""
    scenario = resolve_capture(parse_scenario({"name": "sel", "database": PROCEDURAL["database"] | {
        "source": "both", "select": [{"source": ["studio"], "style": ["normal"]}]},
        "test": {"motions": "captures", "split": "none"}}), [str(d) for d in capture_dirs])
    pipeline.clear_caches()
    for run in plan(scenario, tmp_path):
        training = pipeline.training_motions(run.config, pipeline.test_motion(run))
        captured = [m for m in training if m.source != "procedural"]
        assert captured and {(m.source, m.style) for m in captured} == {("studio", "normal")}
