"""The real run function: no state carried between runs, the worker's code version checked."""

import json

import pytest

from harness.evaluation import pipeline, runner
from harness.evaluation.loading import parse_scenario

TINY = {"name": "pipe", "seed": 3, "database": {"classes": ["walk", "squat", "kick"], "train_demos": 3, "states": 6},
        "test": {"demos_per_class": 1}, "markers": {"count": 40}, "camera": {"azimuth": "random"},
        "engine": {"tracks": {"particles": 40}, "model": {"points": 40}}}


def _rows(runs) -> list[str]:
    """Each run's rows as canonical JSON (timing dropped), after forgetting every cache."""
    pipeline.clear_caches()
    out = []
    for run in runs:
        rows = pipeline.run_one(run)
        out.append(json.dumps([{k: v for k, v in r.items() if k != "ms_per_frame"} for r in rows], sort_keys=True))
    return out


def test_two_runs_in_either_order_give_the_rows_they_give_alone(tmp_path):
    runs = runner.plan(parse_scenario(TINY), tmp_path)
    a, b = runs[0], runs[2]
    assert a.test_class != b.test_class
    alone_a, alone_b = _rows([a]), _rows([b])
    assert _rows([a, b]) == alone_a + alone_b
    assert _rows([b, a]) == alone_b + alone_a
    assert alone_a != alone_b


def test_a_worker_with_other_code_refuses_the_run(tmp_path):
    run = runner.plan(parse_scenario(TINY), tmp_path)[0]
    from dataclasses import replace

    with pytest.raises(runner.RunError, match=r"planned with 0\.0\.0\+other \(every worker must run the same"):
        pipeline.run_one(replace(run, code="0.0.0+other"))


def test_the_viewing_columns_are_where_the_camera_stood(tmp_path):
    """The recorded azimuth, elevation and distance are those of the scene's camera at the first frame, measured
    from its ground truth: the camera's bearing from the look-at point (the mean base xy at 0.9 m) against the
    subject's initial heading; visible markers per frame are the truth's visible count."""
    import numpy as np

    from harness.evaluation.viewing import VIEW_COLUMNS, view_bin
    from harness.geometry import heading

    runs = runner.plan(parse_scenario({**TINY, "methods": ["joint_space"]}), tmp_path)
    for run in runs[:3]:
        row = pipeline.run_one(run)[0]
        truth = pipeline.run_inputs(run).truth
        look_at = np.append(truth.qpos[:, :2].mean(axis=0), 0.9)
        offset = truth.camera_pos[0] - look_at
        bearing = np.degrees(np.arctan2(offset[1], offset[0]) - heading(truth.qpos[0, 3:7]))
        assert set(VIEW_COLUMNS) <= set(row)
        assert (row["view_azimuth_deg"] - bearing + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)
        assert -180.0 <= row["view_azimuth_deg"] < 180.0
        assert row["view_distance_m"] == pytest.approx(np.linalg.norm(offset), rel=1e-9)
        assert row["view_elevation_deg"] == pytest.approx(np.degrees(np.arcsin(offset[2] / np.linalg.norm(offset))))
        assert row["visible_markers"] == pytest.approx((truth.visibility == 0).sum(axis=1).mean())
    assert len({pipeline.run_one(r)[0]["view_azimuth_deg"] for r in runs[:3]}) == 3      # drawn per run
    assert list(view_bin(np.array([0.0, 44.9, 45.0, -90.0, 134.9, 135.0, -180.0, 200.0, np.nan]))) == [
        "front", "front", "side", "side", "side", "back", "back", "back", ""]
