"""Regression against stored metrics: passes on the stored summary, fails on a doctored one, ignores timing."""

import json
import shutil
from pathlib import Path

import pytest

from harness.cli import main
from harness.evaluation import regress

REPO = Path(__file__).resolve().parents[1]
TOLERANCES = REPO / "results" / "baseline" / "tolerances.yaml"
STORED = {"full/correct": 0.75, "full/mpjpe_cam_mm": 80.0, "full/ms_per_frame": 30.0, "gt_base/correct": 0.9,
          "full/base_pos_err_m": 0.10}


@pytest.fixture
def setup(tmp_path):
    """A CI scenario, its current metrics (results/ci/metrics.json) and a baseline stored from them."""
    scenario = tmp_path / "ci.yaml"
    scenario.write_text("name: ci\nseed: 1\n")
    results = tmp_path / "results"
    (results / "ci").mkdir(parents=True)
    (results / "ci" / "metrics.json").write_text(json.dumps(STORED))
    baseline = tmp_path / "baseline"
    baseline.mkdir()
    shutil.copy(TOLERANCES, baseline / "tolerances.yaml")
    args = ["--scenario", str(scenario), "--results", str(results), "--baseline", str(baseline), "--no-run"]
    assert main(["rebaseline", *args]) == 0
    return results / "ci" / "metrics.json", args


def _doctor(path, **changes):
    data = json.loads(path.read_text())
    for k, v in changes.items():
        data[k.replace("__", "/")] = v
    path.write_text(json.dumps(data))


def test_passes_on_the_stored_summary(setup, capsys):
    _, args = setup
    assert main(["regress", *args]) == 0
    out = capsys.readouterr().out
    assert "no regression" in out and "full/mpjpe_cam_mm" in out and "timing" in out


@pytest.mark.parametrize("changes, failing", [
    ({"full__correct": 0.60}, "full/correct"),                # 15 points down (10 allowed)
    ({"full__mpjpe_cam_mm": 80.0 * 1.15 + 5.0 + 0.1}, "full/mpjpe_cam_mm"),
    ({"gt_base__correct": float("nan")}, "gt_base/correct"),  # a metric that disappeared
])
def test_fails_on_a_doctored_summary(setup, capsys, changes, failing):
    path, args = setup
    _doctor(path, **changes)
    assert main(["regress", *args]) == 1
    captured = capsys.readouterr()
    line = next(l for l in captured.out.splitlines() if l.startswith(failing + " "))
    assert line.rstrip().endswith(("REGRESSED", "MISSING"))
    assert failing in captured.err


def test_within_tolerance_and_timing_are_not_gated(setup):
    path, args = setup
    _doctor(path, full__correct=0.71, full__mpjpe_cam_mm=80.0 * 1.15 + 4.9, full__ms_per_frame=300.0,
            full__base_pos_err_m=0.05)
    assert main(["regress", *args]) == 0


def test_compare_rules_by_hand():
    tol = regress.load_tolerances(TOLERANCES)
    table = regress.compare({"a/base_rot_err_deg": 10.0, "a/ms_per_frame": 5.0},
                            {"a/base_rot_err_deg": 12.4, "a/ms_per_frame": 50.0, "a/reproj_px": 1.0}, tol)
    verdicts = dict(zip(table["metric"], table["verdict"]))
    assert verdicts == {"a/base_rot_err_deg": "ok", "a/ms_per_frame": "timing", "a/reproj_px": "new"}
    table = regress.compare({"a/base_rot_err_deg": 10.0}, {"a/base_rot_err_deg": 12.6}, tol)   # > 10*1.15+1
    assert regress.failed(table)


def test_missing_baseline_and_bad_tolerances_are_named(setup, tmp_path):
    _, args = setup
    empty = tmp_path / "nobaseline"
    with pytest.raises(regress.RegressError, match="no stored baseline .*harness rebaseline"):
        regress.check(tmp_path / "results" / "ci", empty)
    bad = tmp_path / "tol.yaml"
    bad.write_text("metrics:\n  correct: {kind: higher, max_dorp: 0.1}\n")
    with pytest.raises(regress.RegressError, match=r"tol.yaml: metrics.correct.max_dorp: unknown key"):
        regress.load_tolerances(bad)
