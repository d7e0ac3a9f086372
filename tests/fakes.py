"""Stand-ins for the pipeline shared by the runner and table tests: a tiny scenario and deterministic rows."""

import time

import numpy as np

from harness.evaluation import runner
from harness.evaluation.methods import CURVE_POINTS, produces

TINY = {"name": "tiny", "seed": 5, "repeats": 2, "database": {"classes": ["walk", "run", "kick"]},
        "test": {"demos_per_class": 1}, "methods": ["full", "gt_base", "no_database"], "occluders": {"preset": "low_wall"},
        "sweep": {"markers.count": [10, 30], "occluders.amount": [0.0, 0.3]}}


def fake_run(run: runner.RunSpec) -> list[dict]:
    """A deterministic stand-in for the pipeline: numbers drawn from the run's seed, shaped like real rows."""
    rng = run.rng()
    classes = list(run.config.classes)
    rows = []
    for method in run.config.methods:
        skill = 0.9 - run.config.occluders.amount - (0.2 if method == "no_database" else 0.0)
        right = rng.random() < skill
        pred = run.test_class if right else classes[(classes.index(run.test_class) + 1) % len(classes)]
        recognises = produces(method, "correct")
        nan = float("nan")
        curve = [int(v) for v in rng.random(CURVE_POINTS) < skill]
        post = _posterior(classes, pred, rng.uniform(-5, 0)) if recognises else {}
        rows.append({"method": method, "class_true": run.test_class, "class_pred": pred if recognises else "",
                     "correct": int(right) if recognises else nan,
                     "frame_accuracy": float(rng.uniform(0.3, 1.0)) if recognises else nan,
                     "time_to_correct_s": float(rng.uniform(0, 2)) if right and recognises else nan,
                     "log_p_true": float(np.log(max(post[run.test_class], 1e-15))) if recognises else nan,
                     "accuracy_curve": curve if recognises else [],
                     "confidence": max(post.values()) if recognises else nan, "posterior_final": post,
                     "angle_rms_deg": float(rng.gamma(4, 2)), "mpjpe_cam_mm": float(rng.gamma(9, 8)),
                     "mpjpe_abs_mm": float(rng.gamma(9, 20)), "base_pos_err_m": float(rng.gamma(3, 0.05)),
                     "base_depth_err_m": float(rng.gamma(2, 0.05)), "base_rot_err_deg": float(rng.gamma(3, 3)),
                     "reproj_px": float(rng.gamma(3, 1)), "ms_per_frame": 12.5,
                     "self_occlusion": 0.2, "obstacle_occlusion": run.config.occluders.amount * 0.8,
                     "n_frames": 60, "mean_flows": float(run.config.markers.count) * 0.6})
    return rows


def _posterior(classes: list[str], pred: str, u: float) -> dict:
    """A final posterior whose argmax is ``pred``: it holds ``1/C + (1 - 1/C) e^u`` (u <= 0), the other classes
    share the rest equally."""
    top = 1.0 / len(classes) + (1.0 - 1.0 / len(classes)) * float(np.exp(u))
    return {c: top if c == pred else (1.0 - top) / (len(classes) - 1) for c in classes}


def slow_fake_run(run):
    time.sleep(0.05)
    return fake_run(run)


def failing_run(run):
    if run.test_class == "run" and run.repeat == 1:
        from harness.errors import HarnessError
        raise HarnessError("kick exploded")
    return fake_run(run)


def slower_fake_run(run):
    """A run slow enough that a process can be killed while runs are in flight (24 runs take 4 s on 2 workers)."""
    time.sleep(0.3)
    return fake_run(run)
