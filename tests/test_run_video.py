"""``harness run-video``: a stored run done again and drawn (camera image, flows, true and estimated body)."""

import cv2
import numpy as np
import pandas as pd
import yaml

from harness.cli import main
from harness.evaluation import metrics, pipeline
from harness.evaluation.methods import EngineRuns
from harness.evaluation.run_video import PANEL_WIDTH, TRUE_RGB, find_run, method_estimate
from harness.pinhole import project

TINY = {
    "name": "rv",
    "seed": 4,
    "database": {"classes": ["walk", "squat"], "train_demos": 3, "states": 6},
    "test": {"demos_per_class": 1},
    "markers": {"count": 50},
    "camera": {"azimuth": 40},
    "occluders": {"preset": "low_wall", "amount": 0.2},
    "engine": {"tracks": {"particles": 40}, "model": {"points": 40}},
    "methods": ["full", "full_smoothed"],
}


def test_run_video_redraws_a_stored_run(tmp_path, capsys):
    path = tmp_path / "rv.yaml"
    path.write_text(yaml.safe_dump(TINY))
    results = tmp_path / "results"
    assert main(["evaluate", str(path), "--results", str(results), "--quiet", "--limit", "1"]) == 0
    rows = pd.read_csv(results / "rv" / "runs.csv")
    key = rows["run_key"].iloc[0]
    _, run = find_run(results / "rv", key)
    inputs = pipeline.run_inputs(run)
    t = len(inputs.obs) // 2
    out, png = tmp_path / "run.mp4", tmp_path / "f.png"
    capsys.readouterr()
    assert main(["run-video", str(results / "rv"), key, "--out", str(out), "--png", str(png), "--frame", str(t)]) == 0
    printed = capsys.readouterr().out
    assert f"{len(inputs.obs)} frames" in printed and f"recognised {rows['class_pred'].iloc[0]}" in printed
    frame = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
    assert frame.shape == (480, 640 + PANEL_WIDTH, 3) and out.stat().st_size > 0
    # The true body is drawn where the ground truth projects: its root joint's dot is green.
    truth = inputs.truth
    root = metrics.camera_qpos(inputs.subject, truth.base_pos_cam, truth.base_quat_cam, truth.qpos[:, 7:])[t, :3]
    u, v = np.round(project(inputs.obs.intrinsics, root)).astype(int)
    assert tuple(frame[v, u]) == TRUE_RGB
    capsys.readouterr()
    assert main(["run-video", str(results / "rv"), "c000/r000/jump/d003", "--out", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no run 'c000/r000/jump/d003'" in err[0] and not (tmp_path / "x.mp4").exists()


def test_run_video_shows_the_methods_own_estimate(tmp_path, capsys):
    """``full_smoothed`` is drawn from its smoothed path (not the causal one), ``no_database`` without a posterior
    panel; the stored run is rebuilt from its stored scene, not from drawing again."""
    path = tmp_path / "rv.yaml"
    path.write_text(yaml.safe_dump(TINY))
    results = tmp_path / "results"
    assert main(["evaluate", str(path), "--results", str(results), "--quiet", "--limit", "1"]) == 0
    key = pd.read_csv(results / "rv" / "runs.csv")["run_key"].iloc[0]
    _, inputs, smoothed = method_estimate(results / "rv", key, "full_smoothed")
    causal = EngineRuns(inputs).from_flows
    np.testing.assert_array_equal(smoothed.qpos, causal.offline.qpos)
    assert np.abs(smoothed.qpos - causal.qpos).max() > 1e-3           # the smoother moved the path
    _, _, given = method_estimate(results / "rv", key, "gt_base")
    np.testing.assert_allclose(given.qpos[:, :3], inputs.truth.base_pos_cam, atol=1e-12)
    capsys.readouterr()
    assert main(["run-video", str(results / "rv"), key, "--method", "no_database", "--out",
                 str(tmp_path / "n.gif")]) == 0
    assert "the method does not recognise" in capsys.readouterr().out
