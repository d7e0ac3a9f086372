"""``harness run-video RESULTS_DIR RUN_KEY --out run.mp4``: watch one run of an evaluation.

The run is done again from its stored scenario (``RESULTS_DIR/scenario.json``) and seed (the pipeline is
deterministic: same seed, same observation and estimate), and the chosen method's own estimate is shown (for
``full_smoothed`` its smoothed path). Each video frame is the scene camera's image with the
observed flows (yellow arrows, red for outliers) and the obstacles, the true body (green) and the engine's
estimate (magenta) drawn over it as skeletons (joint centres joined parent to child), and beside it the class
posterior over time (the true class drawn thick, a cursor at the current frame).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from harness.commands import command
from harness.errors import HarnessError

TRUE_RGB = (40, 220, 60)
ESTIMATE_RGB = (240, 40, 220)
PANEL_WIDTH = 360

def recovering_methods() -> tuple[str, ...]:
    """The registered methods whose estimate has a body to draw."""
    from harness.evaluation.methods import METHODS

    return tuple(name for name, m in METHODS.items() if m.recovers)


class RunVideoError(HarnessError):
    """A run that cannot be found or rendered."""


def _args(p: argparse.ArgumentParser) -> None:
    p.add_argument("results_dir", help="a scenario's results directory (results/<name>)")
    p.add_argument("run_key", help="the run's key, e.g. c000/r000/walk/d008 (column run_key of runs.csv)")
    p.add_argument("--out", required=True, help="video file (.mp4 or .gif)")
    p.add_argument("--method", default="full", choices=recovering_methods(),
                   help="the method whose estimate is shown (default full)")
    p.add_argument("--png", default=None, help="also write frame --frame as a PNG (to look at one still)")
    p.add_argument("--frame", type=int, default=None, help="frame written by --png (default: the middle)")


def find_run(results_dir: Path, run_key: str):
    """The stored scenario of ``results_dir`` and the ``RunSpec`` of ``run_key`` in its plan."""
    from harness.evaluation.runner import plan
    from harness.evaluation.loading import parse_scenario
    from harness.evaluation.scenario import ScenarioError, scenario_hash
    from harness.io import read_input_bytes

    path = results_dir / "scenario.json"
    if not path.is_file():
        raise RunVideoError(f"{path}: no stored scenario (is {results_dir} a results directory of `harness "
                            f"evaluate`?)")
    try:
        data = json.loads(read_input_bytes(path, RunVideoError, "stored scenario", 16 * 2**20))
        scenario = parse_scenario(data["scenario"], str(path))
    except (ValueError, KeyError, TypeError, RecursionError):     # JSON, UTF-8, digits, nesting
        raise RunVideoError(f"{path}: not a stored scenario") from None
    except ScenarioError as exc:
        raise RunVideoError(f"{path}: the stored scenario no longer validates ({exc})") from None
    if data.get("hash") != scenario_hash(scenario):
        print(f"note: {path}: stored under hash {data.get('hash')}, now {scenario_hash(scenario)} (the code or "
              f"scenario changed): the run is done again with the current code", file=sys.stderr)
    runs = {r.key: r for r in plan(scenario, results_dir.parent / "cache")}
    if run_key not in runs:
        example = next(iter(runs)) if runs else "none"
        raise RunVideoError(f"{results_dir}: no run {run_key!r} in the plan of scenario {scenario.name!r} "
                            f"({len(runs)} runs, e.g. {example})")
    return scenario, runs[run_key]


def posterior_panel(post: np.ndarray, classes, label: str, t: int, height: int, width: int = PANEL_WIDTH
                    ) -> np.ndarray:
    """The class posterior ``(T, C)`` up to frame ``t`` as lines over time, ``(height, width, 3) uint8``."""
    import cv2
    import matplotlib

    panel = np.full((height, width, 3), 255, dtype=np.uint8)
    top, bottom, left, right = 30, height - 20 - 14 * len(classes) // 2, 36, width - 10
    T = len(post)
    cmap = matplotlib.colormaps["tab10"]
    cv2.rectangle(panel, (left, top), (right, bottom), (180, 180, 180), 1)
    for y, text in ((top, "1"), (bottom, "0")):
        cv2.putText(panel, text, (left - 14, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    xs = left + (right - left) * np.arange(t + 1) / max(T - 1, 1)
    for c, name in enumerate(classes):
        rgb = tuple(int(255 * v) for v in cmap(c % 10)[:3])
        ys = bottom - (bottom - top) * post[: t + 1, c]
        pts = np.stack([xs, ys], axis=1).round().astype(np.int32)
        cv2.polylines(panel, [pts], False, rgb, 3 if name == label else 1, cv2.LINE_AA)
        row, col = divmod(c, 2)
        cv2.putText(panel, name + (" (true)" if name == label else ""), (left + col * (width // 2 - 10),
                    bottom + 16 + 14 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.38, rgb, 1, cv2.LINE_AA)
    x = int(round(xs[-1]))
    cv2.line(panel, (x, top), (x, bottom), (0, 0, 0), 1)
    best = classes[int(np.argmax(post[t]))]
    cv2.putText(panel, f"class posterior; now: {best} {post[t].max():.2f}", (8, 18), cv2.FONT_HERSHEY_SIMPLEX,
                0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return panel


def method_estimate(results_dir: str | Path, run_key: str, method: str):
    """A stored run done again: its ``RunSpec``, its ``RunInputs`` and method ``method``'s own estimate."""
    from harness.evaluation import pipeline
    from harness.evaluation.methods import METHODS, EngineRuns

    _, run = find_run(Path(results_dir), run_key)
    inputs = pipeline.run_inputs(run)
    est = METHODS[method].estimate(inputs, EngineRuns(inputs))
    if est is None or est.qpos is None:
        raise RunVideoError(f"run {run_key}: the camera saw no flow, there is no estimate to show")
    return run, inputs, est


def blank_panel(text: str, height: int, width: int = PANEL_WIDTH) -> np.ndarray:
    """A white panel ``(height, width, 3) uint8`` with one line of text, beside a method without posteriors."""
    import cv2

    panel = np.full((height, width, 3), 255, dtype=np.uint8)
    cv2.putText(panel, text, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return panel


def render_run(results_dir: str | Path, run_key: str, method: str = "full") -> tuple[list[np.ndarray], float, str]:
    """The frames of one run's video, its frame rate and a one-line summary."""
    import cv2

    from harness.body import body_origins, nominal_body
    from harness.evaluation import metrics
    from harness.pinhole import project
    from harness.scene.rendered import render_frames
    from harness.scene.setup import build_setup
    from harness.scene.simulate import OUTLIER_ID
    from harness.video import draw_flows, draw_skeleton

    run, inputs, est = method_estimate(results_dir, run_key, method)
    obs, truth, body = inputs.obs, inputs.truth, inputs.body
    setup = build_setup(inputs.performed, inputs.scene, nominal_body())
    intr = obs.intrinsics
    true_cam = body_origins(inputs.subject, metrics.camera_qpos(inputs.subject, truth.base_pos_cam,
                                                                truth.base_quat_cam, truth.qpos[:, 7:]))
    est_cam = body_origins(body, est.qpos)
    parents = body.model.body_parentid[1:] - 1
    classes = list(inputs.classes)
    frames = []
    for t, rgb in enumerate(render_frames(setup, setup.motion.qpos)):
        img = draw_flows(rgb, obs.flows[t], truth.marker_ids[t] == OUTLIER_ID)
        # The truth is drawn last: it is the reference the estimate is read against.
        for joints, colour in ((est_cam[t], ESTIMATE_RGB), (true_cam[t], TRUE_RGB)):
            front = joints[:, 2] > 0.05
            draw_skeleton(img, project(intr, np.where(front[:, None], joints, 1.0)), parents, colour, front)
        # A stream's true label changes over time (transition frames have none among the classes).
        true = run.test_class if inputs.labels is None else str(inputs.labels[t])
        cv2.putText(img, f"{run_key}  t={t / obs.fps:.2f}s  true {true} (green), {method} (magenta)",
                    (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
        panel = (posterior_panel(est.class_posterior, classes, true, t, img.shape[0])
                 if est.class_posterior is not None else blank_panel(f"{method}: no recognition", img.shape[0]))
        frames.append(np.concatenate([img, panel], axis=1))
    recognised = est.predicted if est.class_posterior is not None else "nothing (the method does not recognise)"
    summary = (f"{run_key}: true {run.test_class}, recognised {recognised}; obstacle occlusion "
               f"{truth.obstacle_fraction.mean():.2f}, self-occlusion {truth.self_fraction.mean():.2f}")
    return frames, obs.fps, summary


@command("run-video", _args)
def run_video_command(args: argparse.Namespace) -> int:
    """Video of one evaluation run: camera image, flows, obstacles, true and estimated body, class posterior."""
    from harness.video import VideoError, write_video

    from harness.io import check_output_file

    if Path(args.out).suffix.lower() not in (".mp4", ".gif"):
        raise VideoError(f"--out {args.out}: video files must end in .mp4 or .gif")
    check_output_file(args.out)
    if args.png:
        check_output_file(args.png, "--png")
    frames, fps, summary = render_run(args.results_dir, args.run_key, args.method)
    if args.png:
        import cv2

        k = len(frames) // 2 if args.frame is None else args.frame
        if not 0 <= k < len(frames):
            raise RunVideoError(f"--frame={k}: the run has {len(frames)} frames")
        from harness.io import write_atomic

        ok, buf = cv2.imencode(".png", cv2.cvtColor(frames[k], cv2.COLOR_RGB2BGR))
        write_atomic(args.png, lambda fh: fh.write(buf.tobytes()))
    n = write_video(args.out, frames, fps)
    print(f"{args.out}: {n} frames; {summary}")
    return 0
