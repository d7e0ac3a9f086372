"""`harness export`: the runs as files with an index and a loader; what the loader gives back is what the pipeline
hands a method."""

import dataclasses
import json

import numpy as np
import pytest

from harness.cli import main
from harness.evaluation import pipeline, runner
from harness.evaluation.export import (EXPORT_FORMAT, ExportError, export, load_index, load_run, load_runs,
                                       scene_from_dict)
from harness.evaluation.loading import parse_scenario

# Every part of a run that files must carry: a scaled, jittered subject (the motion as observed differs from the
# nominal performance), an obstacle (the truth's occluders), a camera prior (the observation's optional arrays),
# a random azimuth and seeds left to the run (the scene spec as drawn).
SCENE = {"name": "exp", "seed": 11, "database": {"classes": ["walk", "jump"], "train_demos": 2, "states": 4},
         "test": {"demos_per_class": 1}, "markers": {"count": 25}, "camera": {"azimuth": "random"},
         "subject": {"scale": 1.08, "limb_scale": 0.05}, "occluders": {"preset": "pillar", "amount": 0.3},
         "observation": {"camera_prior": "floor", "outliers": 0.1}}
STREAM = {"name": "exps", "seed": 3, "database": {"classes": ["walk", "wave", "squat"], "train_demos": 2, "states": 4},
          "test": {"stream": {"count": 1, "primitives": [2, 2]}}, "markers": {"count": 20},
          "engine": {"belief": {"primitive_switch": 0.01}}}


def _same(a, b, where="") -> None:
    """Field by field, arrays exactly (the same bits), for dataclasses, sequences, mappings and scalars."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape, where
        assert a.dtype.kind == b.dtype.kind or {a.dtype.kind, b.dtype.kind} <= {"i", "u"}, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    else:
        number = (int, float, np.number)
        same_kind = (type(a) is type(b) or (isinstance(a, str) and isinstance(b, str))       # numpy's str_ is a str
                     or (isinstance(a, number) and isinstance(b, number) and not isinstance(a, bool)
                         and not isinstance(b, bool)))                                     # numbers: by value
        assert a == b and same_kind, f"{where}: {a!r} != {b!r}"


@pytest.mark.parametrize("raw", [SCENE, STREAM], ids=["scene", "stream"])
def test_load_of_export_is_what_the_pipeline_hands_a_method(tmp_path, raw):
    scenario = parse_scenario(raw)
    out = tmp_path / "data"
    index = export(scenario, out, tmp_path / "cache", progress=False)
    runs = runner.plan(scenario, tmp_path / "cache")
    assert list(index["run_key"]) == [r.key for r in runs]
    for run in runs:
        inputs = pipeline.run_inputs(run)
        loaded = load_run(out, run.key)
        for name in ("key", "label", "classes", "obs", "truth", "motion", "performed", "labels", "scene"):
            _same(getattr(loaded, name), getattr(inputs, name), name)
        assert loaded.meta["seed"] == run.seed and loaded.meta["test_demo"] == run.test_demo
    if raw is SCENE:
        assert len(loaded.truth.occluders) > 0 and loaded.obs.gravity is not None
        assert not np.array_equal(loaded.motion.qpos, loaded.performed.qpos)       # the scaled subject's
    else:
        assert loaded.labels is not None and len(set(loaded.labels)) >= 3          # two primitives, a transition


def test_the_index_and_one_runs_files_are_as_documented(tmp_path):
    scenario = parse_scenario(SCENE)
    out = tmp_path / "data"
    export(scenario, out, tmp_path / "cache", progress=False)
    index = load_index(out)
    assert list(index.columns) == [
        "run_key", "scenario", "condition", "repeat", "source", "test_class", "test_demo", "seed", "path", "label",
        "split",
        "subject", "demo", "style", "n_frames", "fps", "mean_flows", "markers", "view_azimuth_deg",
        "view_elevation_deg", "view_distance_m", "visible_markers"]
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "index.csv", "runs", "runs.jsonl",
                                                     "runs.jsonl.lock", "scenario.json"]
    about = json.loads((out / "export.json").read_text())
    assert about["format"] == EXPORT_FORMAT == 1 and about["runs"] == 2
    row = index.iloc[0]
    assert sorted(p.name for p in (out / row["path"]).iterdir()) == ["meta.json", "observation.npz",
                                                                     "performed.npz", "truth.npz"]
    meta = json.loads((out / row["path"] / "meta.json").read_text())
    assert meta["split"]["motions"] == "procedural" and meta["split"]["training_subjects"] == ["0", "1"]
    assert str(row["subject"]) == str(meta["split"]["subject"]) and int(row["subject"]) >= 1000
    assert scene_from_dict(meta["scene"]).camera.azimuth == pytest.approx(meta["scene"]["camera"]["azimuth"])
    assert [r.key for r in load_runs(out)] == list(index["run_key"])


def test_an_export_resumes_and_is_refused_when_stale(tmp_path, capsys):
    scenario_file = tmp_path / "exp.yaml"
    scenario_file.write_text(json.dumps(SCENE))
    out, results = tmp_path / "data", tmp_path / "results"
    args = ["export", str(scenario_file), "--out", str(out), "--results", str(results), "--quiet"]
    assert main(args + ["--limit", "1"]) == 0
    assert len(load_index(out)) == 1
    first = (out / "runs" / "c000" / "r000" / "jump" / "d002" / "observation.npz").read_bytes()
    assert main(args) == 0
    assert len(load_index(out)) == 2
    assert (out / "runs" / "c000" / "r000" / "jump" / "d002" / "observation.npz").read_bytes() == first
    assert "2 runs ->" in capsys.readouterr().out
    scenario_file.write_text(json.dumps({**SCENE, "seed": 12}))
    assert main(args) == 2
    assert "pass --fresh" in capsys.readouterr().err
    assert main(args + ["--fresh"]) == 0


def test_the_loader_refuses_what_is_not_an_export(tmp_path):
    with pytest.raises(ExportError, match="no such export description file"):
        load_index(tmp_path)
    with pytest.raises(ExportError, match="not a run key"):
        load_run(tmp_path, "../../etc/passwd")
    (tmp_path / "runs" / "c000" / "r000" / "walk" / "d000").mkdir(parents=True)
    (tmp_path / "runs" / "c000" / "r000" / "walk" / "d000" / "meta.json").write_text('{"format": 9}')
    with pytest.raises(ExportError, match="export format 9, this loader reads 1"):
        load_run(tmp_path, "c000/r000/walk/d000")
