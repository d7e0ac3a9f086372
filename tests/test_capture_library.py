"""The repository's capture library (``captures/``): complete and loadable without ``../shared``, every row where
its source says it is, and retargeting a source row again gives the stored trajectory."""

import csv
import shutil

import numpy as np
import pytest

from conftest import require_mocap
from harness.evaluation.loading import load_scenario
from harness.evaluation.scenario_captures import LIBRARY, resolve_capture
from harness.motion.captures import read_manifest, retarget_rows, row_motions
from harness.motion.library import (KNOWN_TERMS, MAX_LIBRARY_BYTES, TERMS_NAME, LibraryError, build_library,
                                    check_library)

ROOT = LIBRARY.parent


def test_the_library_is_complete_without_the_shared_captures():
    counts = check_library(LIBRARY)
    assert counts == {"bandai": 248, "cmu": 76}
    size = sum(f.stat().st_size for f in LIBRARY.rglob("*") if f.is_file())
    assert size <= MAX_LIBRARY_BYTES
    for name in counts:
        assert (LIBRARY / name / TERMS_NAME).read_text() == KNOWN_TERMS[name]
    assert sorted(p.name for p in (LIBRARY / "bandai").glob("LICENSE*")) == ["LICENSE-dataset-1", "LICENSE-dataset-2"]


def test_the_main_job_plays_back_captured_people_from_the_library(monkeypatch):
    monkeypatch.delenv("HARNESS_MOCAP_DIR", raising=False)
    scenario = resolve_capture(load_scenario(ROOT / "scenarios" / "default.yaml"))
    assert scenario.database.capture_dirs == (str(LIBRARY / "cmu"), str(LIBRARY / "bandai"))
    assert scenario.test.motions == "both" and scenario.database.source == "both" and scenario.database.by_source


@pytest.mark.parametrize("name", ["cmu", "bandai"])
def test_every_source_row_is_in_the_library_as_its_manifest_says(name):
    source = require_mocap().parent / name
    if not (source / "MANIFEST.csv").is_file():
        pytest.skip(f"{source} is absent")
    rows = read_manifest(source / "MANIFEST.csv")
    with open(LIBRARY / name / "MANIFEST.csv", newline="") as fh:
        stored = list(csv.DictReader(fh))
    assert [(r.file, r.start, r.end, r.subject, r.label, r.style) for r in rows] == [
        (s["source_file"], int(s["source_start"]), int(s["source_end"]), s["subject"], s["class"], s["style"])
        for s in stored]


def test_retargeting_a_source_row_again_gives_the_stored_trajectory(body):
    """Three short rows (an AMC row, a BVH row of the built-in tables, a Bandai row through its mapping): the
    library holds what the retargeting gives, to single precision."""
    cmu = require_mocap()
    bandai = cmu.parent / "bandai"
    if not bandai.is_dir():
        pytest.skip(f"{bandai} is absent")
    for source, pick in ((cmu, ("02_05.amc", "09_01.bvh")), (bandai, ("dataset-1_walk_normal_002.bvh",))):
        rows = [r for r in read_manifest(source / "MANIFEST.csv") if r.file in pick]
        rows = [min((r for r in rows if r.file == f), key=lambda r: r.end - r.start) for f in pick]
        fresh = [m for m, _ in retarget_rows(source, rows, 30.0, body)]
        library = read_manifest(LIBRARY / source.name / "MANIFEST.csv")
        stored = row_motions(LIBRARY / source.name, [library[[r.line for r in read_manifest(
            source / "MANIFEST.csv")].index(row.line)] for row in rows])
        for a, b in zip(fresh, stored):
            assert (a.label, a.subject, a.demo, a.source, a.style) == (b.label, b.subject, b.demo, b.source, b.style)
            np.testing.assert_allclose(b.qpos, a.qpos, rtol=1e-6, atol=2e-6)


def test_a_library_is_built_checked_and_refused_without_terms(tmp_path, body):
    cmu = require_mocap()
    source = tmp_path / "cmu"
    source.mkdir()
    shutil.copyfile(cmu / "09_01.bvh", source / "09_01.bvh")
    (source / "MANIFEST.csv").write_text("file,format,skeleton,subject,trial,class,start,end,fps,style\n"
                                         "09_01.bvh,bvh,,9,1,run,1,61,120,\n09_01.bvh,bvh,,9,1,run,61,121,120,fast\n")
    quality = build_library([source], tmp_path / "lib", body)
    assert [q["within_limits"] for q in quality["cmu"]] == [True, True]
    assert check_library(tmp_path / "lib") == {"cmu": 2}
    motions = row_motions(tmp_path / "lib" / "cmu", read_manifest(tmp_path / "lib" / "cmu" / "MANIFEST.csv"))
    assert [m.style for m in motions] == ["", "fast"] and [m.demo for m in motions] == ["09_01:1-61", "09_01:61-121"]
    (tmp_path / "lib" / "cmu" / "stray.npz").write_bytes(b"")
    with pytest.raises(LibraryError, match="files no manifest row names: stray.npz"):
        check_library(tmp_path / "lib")
    other = tmp_path / "studio"
    shutil.copytree(source, other)
    with pytest.raises(LibraryError, match="no terms of use for set 'studio'"):
        build_library([other], tmp_path / "lib2", body)
