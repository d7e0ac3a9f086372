"""Scenario files: validation errors that name the key, defaults, the sweep grid, and the CLI's exit 2."""

from pathlib import Path

import pytest

from harness.cli import main
from harness.evaluation.loading import load_scenario, parse_scenario
from harness.evaluation.scenario import PROCEDURAL_CLASSES, ScenarioError, scenario_hash
from harness.evaluation.scenario_captures import resolve_capture
from harness.evaluation.sweep import conditions

from conftest import require_mocap

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def _error(raw) -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(raw, "s.yaml")
    return str(info.value)


@pytest.mark.parametrize(
    "raw, expected",
    [
        ({"name": "x", "camera": {"distnce": 3}}, "s.yaml: camera.distnce: unknown key"),
        ({"name": "x", "bogus": 1}, "s.yaml: bogus: unknown key"),
        ({"name": "x", "sweep": {"markers.count": []}}, "s.yaml: sweep['markers.count']: empty list"),
        (
            {"name": "x", "database": {"classes": ["walk", "run", "jump", "wlak"]}},
            "s.yaml: database.classes[3]: unknown class 'wlak' (valid: walk, run,",
        ),
        ({"name": "x", "markers": {"count": "many"}}, "s.yaml: markers.count: Input should be a valid integer"),
        ({"name": "x", "camera": {"azimuth": "left"}}, "s.yaml: camera.azimuth: Input should be a valid number"),
        (
            {"name": "x", "sweep": {"markers.count": [10, -3]}},
            "s.yaml: sweep['markers.count'][1]: at least one marker is needed (got -3)",
        ),
        ({"name": "x", "sweep": {"markers.cont": [10]}}, "s.yaml: sweep['markers.cont']: unknown key (valid: "),
        ({"name": "x", "sweep": {"markers.count": 10}}, "s.yaml: sweep['markers.count']: must be a list"),
        ({"name": "x", "engine": {"spawn": {"distance": [5, 2]}}}, "s.yaml: engine.spawn.distance: must increase"),
        (
            {"name": "x", "engine": {"init_distance": [2, 5]}},
            "s.yaml: engine.init_distance: moved to engine.spawn.distance",
        ),
        (
            {"name": "x", "engine": {"tracks": {"particles": 3}}},
            "s.yaml: engine: tracks.particles (3) must be at least the tracks spawned",
        ),
        (
            {"name": "x", "sweep": {"engine.particles": [10]}},
            "s.yaml: sweep['engine.particles']: moved to engine.tracks.particles",
        ),
        ({"name": "x", "test": {"split": "all"}}, "s.yaml: test.split: 'all' is now test.split: none"),
        (
            {"name": "x", "methods": ["full", "best"]},
            "s.yaml: methods[1]: unknown method 'best' (built in: full, full_smoothed, gt_base",
        ),
        ({"seed": 3}, "s.yaml: name: required key is missing"),
    ],
)
def test_errors_name_the_key_and_what_was_expected(raw, expected):
    assert _error(raw).startswith(expected)


def test_a_five_line_scenario_gets_the_documented_defaults():
    s = parse_scenario({"name": "small", "sweep": {"engine.tracks.particles": [50, 100]}})
    assert s.classes == PROCEDURAL_CLASSES and s.database.train_demos == 8 and s.database.states == 20
    assert s.database.fps == 30.0 and s.test.demos_per_class == 2 and s.test.motions == "procedural"
    # A swept key's section holds the first condition's value (its unswept value is never run).
    assert (s.engine.tracks.particles, s.engine.model.points, s.engine.model.seed, s.engine.spawn.distance) == \
        (50, 120, 7, (2.0, 8.0))
    assert parse_scenario({"name": "small"}).engine.tracks.particles == 500
    assert s.methods == ("full", "full_smoothed", "gt_base", "no_database", "bottom_up", "joint_space")


def test_conditions_are_the_cartesian_product_last_key_fastest():
    s = parse_scenario({"name": "g", "sweep": {"markers.count": [10, 20], "camera.azimuth": [0, "random", 90]}})
    conds = conditions(s)
    assert [(c.config.markers.count, c.config.camera.azimuth) for c in conds] == \
        [(10, 0), (10, "random"), (10, 90), (20, 0), (20, "random"), (20, 90)]
    assert conds[1].label == "markers.count=10,camera.azimuth=random"
    assert all(c.config.sweep == {} for c in conds)
    assert [c.label for c in conditions(parse_scenario({"name": "n"}))] == ["base"]


def test_hash_changes_with_content_only():
    a = parse_scenario({"name": "h", "seed": 1})
    assert scenario_hash(a) == scenario_hash(parse_scenario({"seed": 1, "name": "h", "repeats": 1}))
    assert scenario_hash(a) != scenario_hash(parse_scenario({"name": "h", "seed": 2}))


def test_yaml_errors_name_the_file_and_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ncamera: {distance: 3\nseed: 2\n")
    with pytest.raises(ScenarioError, match=r"bad.yaml: line \d+ not valid YAML"):
        load_scenario(bad)
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "missing.yaml")


def test_evaluate_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "typo.yaml"
    bad.write_text("name: typo\ncamera:\n  distnce: 4\n")
    results = tmp_path / "results"
    assert main(["evaluate", str(bad), "--results", str(results)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {bad}: camera.distnce: unknown key"]
    assert not results.exists()


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_scenarios_validate(path):
    s = load_scenario(path)
    assert s.name == path.stem
    assert len(conditions(s)) >= 1


def test_capture_classes_are_checked_against_the_manifest():
    mocap = require_mocap()
    s = parse_scenario({"name": "m", "database": {"source": "captures", "classes": ["walk", "wlak"]},
                        "test": {"motions": "captures", "split": "none"}})
    with pytest.raises(ScenarioError, match=r"database.classes\[1\]: unknown class 'wlak' \(valid: "):
        resolve_capture(s, mocap)
    ok = resolve_capture(parse_scenario({"name": "m", "database": {"source": "captures"},
                                         "test": {"motions": "captures", "split": "none"}}), mocap)
    assert "walk" in ok.database.classes and ok.database.capture_dirs == (str(mocap.resolve()),)
    assert ok.database.capture_sets == (mocap.resolve().name,)


def test_no_capture_set_is_named(monkeypatch, tmp_path):
    from harness.evaluation import scenario_captures

    monkeypatch.delenv("HARNESS_MOCAP_DIR", raising=False)
    monkeypatch.setattr(scenario_captures, "LIBRARY", tmp_path / "no_library")
    s = parse_scenario({"name": "m", "database": {"source": "captures"}, "test": {"motions": "captures"}})
    with pytest.raises(ScenarioError, match=r"database.capture_sets: no capture set \(give --mocap-dir DIR"):
        resolve_capture(s)
    s = parse_scenario({"name": "m", "database": {"source": "captures", "capture_sets": ["cmu"]},
                        "test": {"motions": "captures"}})
    with pytest.raises(ScenarioError, match=r"database.capture_sets\[0\]: no capture set 'cmu'"):
        resolve_capture(s)


def test_procedural_classes_are_the_performers():
    from harness.motion import performer

    assert PROCEDURAL_CLASSES is performer.CLASSES          # one list, not a copy that could drift


ROOT = Path(__file__).resolve().parents[1]


def test_the_documented_schema_is_the_generated_one():
    from harness.evaluation.schema_docs import schema_markdown
    from harness.evaluation.sweep import sweepable_keys

    doc = (ROOT / "docs" / "evaluation.md").read_text()
    block = doc.split("<!-- schema:begin -->\n")[1].split("<!-- schema:end -->")[0]
    assert block == schema_markdown()
    for key in sweepable_keys():
        assert f"`{key}`" in doc, key


def test_engine_reaches_every_tracker_setting_by_name():
    import dataclasses

    from harness.engine import TrackerConfig
    from harness.evaluation.scenario import EngineConfig, tracker_config

    names = [f.name for f in dataclasses.fields(TrackerConfig)]
    assert list(EngineConfig.model_fields) == names
    s = parse_scenario({"name": "e", "engine": {"motion": {"guide_fraction": 0.2}, "spawn": {"elevation": [0, 20]}},
                        "sweep": {"engine.likelihood.n_eff_filter": [2.0, 6.0]}})
    assert tracker_config(s) == TrackerConfig.from_dict({"motion.guide_fraction": 0.2, "spawn.elevation": (0.0, 20.0),
                                                         "likelihood.n_eff_filter": 2.0})
    assert [c.config.engine.likelihood.n_eff_filter for c in conditions(s)] == [2.0, 6.0]


def test_scenario_sections_are_the_scene_specs():
    from harness.evaluation.scenario import scene_spec
    from harness.scene.spec import CameraSpec, ObservationSpec, OccluderSpec, SubjectSpec
    import numpy as np

    s = parse_scenario({"name": "d", "markers": {"seed": 4}, "occluders": {"seed": 1}})
    spec = scene_spec(s, np.random.default_rng(0))
    assert spec.camera == CameraSpec() and spec.observation == ObservationSpec()
    assert spec.occluders == OccluderSpec(seed=1) and spec.subject == SubjectSpec()
    assert spec.camera.look_at_height == 0.9 and "follow" in str(CameraSpec.__dataclass_fields__["motion"].metadata)
    assert parse_scenario({"name": "f", "camera": {"motion": "follow"}}).camera.motion == "follow"


def test_the_code_version_is_part_of_the_hash(monkeypatch):
    import harness.evaluation.scenario as sc

    s = parse_scenario({"name": "h"})
    before = scenario_hash(s)
    monkeypatch.setattr(sc, "code_version", lambda: "0.1.0+other")
    assert scenario_hash(s) != before


def test_the_code_version_follows_the_shipped_tables_and_not_the_result_formatting(monkeypatch, tmp_path):
    """A refitted table (``*.json``: the performer's calibration, the human floor) is new code; a change to a
    results-only module is not."""
    import harness.version as version

    (tmp_path / "evaluation").mkdir()
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "table.json").write_text("[1]\n")
    (tmp_path / "evaluation" / "report.py").write_text("y = 1\n")
    monkeypatch.setattr(version, "PACKAGE_DIR", tmp_path)
    seen = []
    for path, text in ((None, None), ("table.json", "[2]\n"), ("evaluation/report.py", "y = 2\n")):
        if path:
            (tmp_path / path).write_text(text)
        version.code_version.cache_clear()
        seen.append(version.code_version())
    version.code_version.cache_clear()
    assert seen[0] != seen[1] == seen[2]


def test_the_keys_of_before_the_capture_sets_are_refused_with_their_new_form():
    with pytest.raises(ScenarioError, match=r"w.yaml: database.with_captures: no longer a key: database.source: both"):
        parse_scenario({"name": "w", "database": {"with_captures": True}}, "w.yaml")
    with pytest.raises(ScenarioError, match=r"w.yaml: test.split: 'leave_one_out' is now test.split: row"):
        parse_scenario({"name": "w", "test": {"split": "leave_one_out"}}, "w.yaml")
    with pytest.raises(ScenarioError, match=r"w.yaml: test.motions: 'procedural' tests procedural demonstrations"):
        parse_scenario({"name": "w", "database": {"source": "captures"}}, "w.yaml")


def test_both_sources_train_on_the_other_subjects_captures(tmp_path, monkeypatch):
    """A database of both sources: the procedural demos plus every capture demo whose subject is not the
    capture test motion's (two rows of subject 2 and one of subject 9 here)."""
    import numpy as np

    from harness.evaluation import pipeline
    from harness.motion import Motion

    directory = require_mocap()
    for name in ("02_01.amc", "02.asf", "09_01.bvh"):     # copies: a link out of the directory is refused
        (tmp_path / name).write_bytes((directory / name).read_bytes())
    (tmp_path / "MANIFEST.csv").write_text(
        "file,format,skeleton,subject,trial,class,start,end,fps\n02_01.amc,amc,02.asf,2,1,walk,0,41,120\n"
        "02_01.amc,amc,02.asf,2,1,walk,41,82,120\n09_01.bvh,bvh,,9,1,run,1,41,120\n")
    s = resolve_capture(parse_scenario({"name": "w", "database": {"source": "both", "train_demos": 1, "states": 4,
                                                                  "classes": ["walk", "run"]},
                                        "test": {"motions": "captures", "split": "subject"}}), tmp_path)
    test = Motion(qpos=np.tile(np.r_[0, 0, 1, 1, 0, 0, 0, np.zeros(50)], (2, 1)), fps=30.0, label="run",
                  subject="9", source=tmp_path.name)
    pipeline.clear_caches()
    motions = pipeline.training_motions(s, test)
    assert [(m.source == "procedural", m.label, m.subject) for m in motions] == [
        (True, "walk", "0"), (True, "run", "0"), (False, "walk", "2"), (False, "walk", "2")]


def test_every_swept_condition_is_validated_as_written_not_the_base():
    """The unswept value of a swept key is never run, so a rule between fields holds per condition: amount 0.4
    beside a swept preset is valid, and the condition that breaks a rule is named."""
    s = parse_scenario({"name": "p", "occluders": {"amount": 0.4}, "sweep": {"occluders.preset": ["pillar", "boxes"]}})
    assert [(c.config.occluders.preset, c.config.occluders.amount) for c in conditions(s)] == [
        ("pillar", 0.4), ("boxes", 0.4)]
    with pytest.raises(ScenarioError, match=r"s.yaml: occluders.amount: preset 'none' hides nothing.*"
                                            r"\(condition occluders.preset=none\)"):
        parse_scenario({"name": "p", "occluders": {"amount": 0.4},
                        "sweep": {"occluders.preset": ["pillar", "none"]}}, "s.yaml")
    with pytest.raises(ScenarioError, match=r"camera.distance: .*inside the standing subject.*"
                                            r"\(condition camera.distance=0.05\)"):
        parse_scenario({"name": "c", "camera": {"elevation": 0}, "sweep": {"camera.distance": [4, 0.05]}}, "c.yaml")
    with pytest.raises(ScenarioError, match=r"sweep\['markers.count'\]\[1\]: at most 10000 markers"):
        parse_scenario({"name": "m", "sweep": {"markers.count": [10, 20000]}}, "m.yaml")
    with pytest.raises(ScenarioError, match=r"v.yaml: camera.motion: observation.mode 'video' .* static camera "
                                            r"\(condition camera.motion=orbit\)"):
        parse_scenario({"name": "v", "observation": {"mode": "video"},
                        "sweep": {"camera.motion": ["static", "orbit"]}}, "v.yaml")


def test_yaml_anchors_and_merge_keys_still_work(tmp_path):
    path = tmp_path / "a.yaml"
    path.write_text("name: a\nseed: &s 4\ndatabase: {seed: *s}\n"
                    "engine: {tracks: {<<: {particles: 50, particles_max: 60}, particles: 80}}\n")
    s = load_scenario(path)
    assert (s.seed, s.database.seed, s.engine.tracks.particles, s.engine.tracks.particles_max) == (4, 4, 80, 60)


def test_capture_classes_are_checked_in_every_condition(tmp_path):
    mocap = require_mocap()
    s = parse_scenario({"name": "m", "database": {"source": "captures"}, "test": {"motions": "captures"},
                        "sweep": {"database.classes": [["walk"], ["walk", "wlak"]]}})
    with pytest.raises(ScenarioError, match=r"s.yaml: database.classes\[1\]: unknown class 'wlak' .*"
                                            r"\(condition database.classes="):
        resolve_capture(s, mocap, where="s.yaml")
