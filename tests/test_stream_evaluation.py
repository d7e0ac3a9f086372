"""Streams in the evaluation: the scenario section, the plan, a real stream run, the tables, timelines and report."""

import numpy as np
import pandas as pd
import pytest

from harness.evaluation import pipeline, runner
from harness.evaluation.report import make_report
from harness.evaluation.loading import parse_scenario
from harness.evaluation.scenario import ScenarioError
from harness.evaluation.tables import STREAM_HEADLINE, headline, summary

TINY = {"name": "tiny_stream", "seed": 3, "database": {"classes": ["walk", "squat", "kick"], "train_demos": 3,
                                                        "states": 6},
        "test": {"stream": {"count": 2, "primitives": [3, 3]}}, "markers": {"count": 40},
        "engine": {"tracks": {"particles": 40}, "model": {"points": 40}, "belief": {"primitive_switch": 0.02}},
        "methods": ["joint_space"]}


@pytest.mark.parametrize("raw, match", [
    ({"test": {"stream": {"takes": ["13_29"]}}}, r"test.stream.takes: a capture take is tested against a database"),
    ({"test": {"motions": "captures", "stream": {}}}, r"test.stream: procedural streams are performed by held-out"),
    ({"database": {"source": "captures"}, "test": {"motions": "captures", "split": "none",
                                                     "stream": {"takes": ["13_29"]}}},
     r"test.stream.takes: a capture take is tested against a database of the capture rows without its own"),
    ({"test": {"stream": {"primitives": [1, 3]}}}, r"test.stream.primitives: must be \[min, max\]"),
    ({"test": {"stream": {"count": 0}}}, r"test.stream.count"),
])
def test_stream_sections_are_checked(raw, match):
    with pytest.raises(ScenarioError, match=match):
        parse_scenario({"name": "s"} | raw)


def test_a_stream_plan_has_one_run_per_stream(tmp_path):
    runs = runner.plan(parse_scenario(TINY | {"repeats": 2}), tmp_path)
    assert [r.key for r in runs] == ["c000/r000/stream/d000", "c000/r000/stream/d001", "c000/r001/stream/d000",
                                     "c000/r001/stream/d001"]
    assert len({r.seed for r in runs}) == 4


def test_a_stream_run_is_scored_per_frame_and_switching_follows_the_changes(tmp_path):
    """Joint-space recognition (true angles) of a stream of three primitives: with the switching recursion it
    follows the primitive changes; without (primitive_switch 0) it follows them worse."""
    pipeline.clear_caches()
    scenario = parse_scenario(TINY)
    run = runner.plan(scenario, tmp_path)[0]
    stream = pipeline.test_stream(run)
    assert len(set(stream.primitives)) >= 2
    row = pipeline.run_one(run)[0]
    assert row["class_true"] == "stream" and row["method"] == "joint_space"
    assert row["segments_true"] == [[s.label, s.start, s.stop] for s in stream.segments]
    assert {"frame_accuracy", "edit_score", "f1_10", "f1_25", "f1_50", "boundary_delay_s", "segments_pred"} <= set(row)
    assert "correct" not in row
    isolated = parse_scenario(TINY | {"engine": TINY["engine"] | {"belief": {"primitive_switch": 0.0}}})
    row0 = pipeline.run_one(runner.plan(isolated, tmp_path)[0])[0]
    # With true angles the switching recursion meets issue 15's stream target (frame accuracy 0.85); the
    # isolated one, which can only drift between primitives through their joint normalisation, does worse.
    assert row["frame_accuracy"] >= 0.85
    assert row["frame_accuracy"] > row0["frame_accuracy"]


def _stream_rows() -> pd.DataFrame:
    segs_true = [["walk", 0, 30], ["transition", 30, 40], ["squat", 40, 90]]
    rows = []
    for k, (acc, pred) in enumerate([(0.9, [["walk", 0, 42], ["squat", 42, 90]]),
                                     (0.5, [["walk", 0, 70], ["squat", 70, 90]])]):
        for method in ("full", "no_database"):
            rec = method == "full"
            rows.append({"run_key": f"c000/r000/stream/d{k:03d}", "condition": "base", "method": method,
                         "class_true": "stream", "segments_true": segs_true,
                         "segments_pred": pred if rec else [], "frame_accuracy": acc if rec else np.nan,
                         "edit_score": 1.0 if rec else np.nan, "f1_10": 1.0 if rec else np.nan,
                         "f1_25": 1.0 if rec else np.nan, "f1_50": 0.5 if rec else np.nan,
                         "boundary_delay_s": 0.1 if rec else np.nan, "mpjpe_cam_mm": 100.0 + k,
                         "n_frames": 90, "mean_flows": 50.0, "self_occlusion": 0.2, "obstacle_occlusion": 0.0,
                         "ms_per_frame": 10.0})
    return pd.DataFrame(rows)


def test_stream_tables_timelines_and_report(tmp_path):
    rows = _stream_rows()
    table = headline(summary(rows, [], n_boot=200), [], STREAM_HEADLINE)
    full = table[table["method"] == "full"].iloc[0]
    assert full["frame_accuracy"].startswith("0.7 [") and full["runs"] == 2
    assert table[table["method"] == "no_database"].iloc[0]["f1_25"] == "–"
    scenario = parse_scenario(TINY | {"methods": ["full", "no_database"]})
    path = make_report(scenario, tmp_path, rows)
    text = path.read_text()
    assert "## Timelines" in text and "edit_score" in text and "Confusion" not in text
    for k in range(2):
        assert (tmp_path / f"plots/timelines/c000_r000_stream_d{k:03d}.png").stat().st_size > 1000
    worst = pd.read_csv(tmp_path / "worst_runs.csv")
    assert worst["run_key"].tolist() == ["c000/r000/stream/d001", "c000/r000/stream/d000"]
