"""What one run may cost, checked for every condition of a scenario at load, before anything is trained.

The scene and engine specs bound each setting on its own (markers, image side, particles, ...); settings that
are each fine can still multiply into a run no machine can hold (10,000 markers over a 20-primitive stream at
1000 fps). ``check_run`` estimates a run's frames and peak memory from its condition and refuses one beyond
``MAX_RUN_FRAMES`` or ``MAX_RUN_BYTES``. The estimate is an upper bound from the arrays each stage
allocates, with constants measured on this code (the comments say where); it admits every shipped scenario
with a wide margin (the default scenario's runs are estimated at about 0.5 GB).

Capture scenarios take their frame counts from the capture files, which are bounded by
``harness.io.MAX_TEXT_BYTES``; their estimate counts the engine and the database only.
"""

from __future__ import annotations

import math

MAX_CONDITIONS = 1_000          # sweep conditions (the Cartesian product); larger grids are refused at once
MAX_SWEEP_VALUES = 1_000        # values of one swept key
MAX_RUN_FRAMES = 20_000         # frames of one run (11 minutes at 30 fps)
MAX_RUN_BYTES = 2 * 2**30       # estimated peak memory of one run (two run side by side on a 2-core machine)
PRIMITIVE_S_BOUND = 5.0         # s: no procedural demonstration lasts longer (measured: at most 3.5 s, squat;
                                # tests/test_limits.py checks every class)

PROCESS_BYTES = 256 * 2**20     # interpreter, MuJoCo, numba: a worker's resident size before its first run
HYPOTHESIS_POINT_BYTES = 256    # engine, first frame: measured 183-200 B per hypothesis x model point
MARKER_FRAME_BYTES = 256        # scene: world, camera, normals, pixels, visibility, noise per marker and frame
FLOW_BYTES = 64                 # observation and ground truth per flow (row, id, ...)
STATE_POINT_BYTES = 512         # database transform: means, covariances of positions and velocities
TRAINING_BYTES = 8 * 4          # per training frame and (feature + state): the stacked features and hmmlearn's
                                # forward, backward and posterior arrays
FEATURES = 106                  # joint angles, their velocities, base linear and angular velocity
RENDER_PIXEL_BYTES = 32         # rendered mode: RGB frame, depth, grey pyramids of Lucas-Kanade


class LimitError(ValueError):
    """A condition whose run would exceed a stated limit; ``key`` names the setting that drives it."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


def run_frames(config) -> int | None:
    """An upper bound of a run's frames for a condition (a ``Scenario``), None for captures."""
    fps = float(config.database.fps)
    stream = config.test.stream
    if config.test.captures or (stream is not None and stream.takes is not None):
        return None
    if stream is not None and stream.takes is None:
        return int(math.ceil(stream.primitives[1] * (PRIMITIVE_S_BOUND + stream.transition_s[1]) * fps)) + 1
    return int(math.ceil(PRIMITIVE_S_BOUND * fps)) + 1


def run_bytes(config) -> dict[str, int]:
    """The estimated peak memory of one run of a condition, by stage (bytes)."""
    eng, cam, obs = config.engine, config.camera, config.observation
    cell = eng.likelihood.open_cell_px
    frames = run_frames(config) or 0
    markers = config.markers.count
    flows_per_frame = markers * (1.0 + obs.outliers)
    n_classes = len(config.database.classes or ()) or 10
    hypotheses = eng.tracks.particles * max(eng.spawn.factor, eng.tracks.weigh_classes)
    states = config.database.states * (2 if config.database.mirrored else 1)    # a chain per side
    out = {
        "process": PROCESS_BYTES,
        "engine": HYPOTHESIS_POINT_BYTES * hypotheses * eng.model.points + 8 * hypotheses * int(flows_per_frame),
        "database": STATE_POINT_BYTES * n_classes * states * eng.model.points,
        "scene": MARKER_FRAME_BYTES * frames * markers + int(FLOW_BYTES * frames * flows_per_frame),
        "open_region": 24 * math.ceil(cam.width / cell) * math.ceil(cam.height / cell),
        "rendered": RENDER_PIXEL_BYTES * cam.width * cam.height if obs.mode == "rendered" else 0,
    }
    if config.database.learns_procedural:
        train_frames = n_classes * config.database.train_demos * (int(PRIMITIVE_S_BOUND * config.database.fps) + 1)
        out["training"] = TRAINING_BYTES * train_frames * (FEATURES + config.database.states)
    return out


def check_run(config) -> None:
    """Raise ``LimitError`` if a run of this condition would exceed ``MAX_RUN_FRAMES`` or ``MAX_RUN_BYTES``."""
    frames = run_frames(config)
    if frames is not None and frames > MAX_RUN_FRAMES:
        key = "test.stream" if config.test.stream is not None else "database.fps"
        raise LimitError(key, f"a run would have up to {frames} frames, more than {MAX_RUN_FRAMES}")
    parts = run_bytes(config)
    total = sum(parts.values())
    if total > MAX_RUN_BYTES:
        stage = max((k for k in parts if k != "process"), key=parts.get)
        key = {
            "engine": "engine.tracks.particles",
            "database": "database.states",
            "scene": "markers.count",
            "open_region": "engine.likelihood.open_cell_px",
            "rendered": "camera.width",
            "training": "database.train_demos",
        }[stage]
        raise LimitError(key, f"a run would take about {total / 2**30:.1f} GB ({stage} {parts[stage] / 2**30:.1f} "
                              f"GB), more than {MAX_RUN_BYTES / 2**30:g} GB")
