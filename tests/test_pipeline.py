"""The real run function: no state carried between runs, the worker's code version checked."""

import json

import pytest

from harness.evaluation import pipeline, runner
from harness.evaluation.scenario import parse_scenario

TINY = {"name": "pipe", "seed": 3, "database": {"classes": ["walk", "squat", "kick"], "train_demos": 3, "states": 6},
        "test": {"demos_per_class": 1}, "markers": {"count": 40}, "camera": {"azimuth": "random"},
        "engine": {"particles": 40, "model_points": 40}}


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
