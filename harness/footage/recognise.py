"""The engine on each followed person: the camera (intrinsics, the elevation prior), each person's flows as an
observation, the motion database at the video's frame rate, and a summary of what the engine answered.

The engine is used through ``Tracker(db, body)`` with its default settings and the ``Estimate`` it returns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harness.errors import HarnessError
from harness.footage.pipeline import PersonTrack
from harness.observation import Observation
from harness.pinhole import Intrinsics

DEFAULT_HFOV_DEG = 60.0      # a common lens (about 30 mm on full frame) when the camera's is not known
# The default database is `harness train-database`'s recipe (a test checks these against its defaults):
# all procedural primitives, 8 demonstrations each, 20 states per side, both-handed, seed 0, at the video's fps.
DEFAULT_DEMOS = 8
DEFAULT_STATES = 20
DEFAULT_SEED = 0
MAX_DATABASE_BYTES = 1 << 30


class CameraInputError(HarnessError):
    """Camera parameters given on the command line that describe no camera."""


def intrinsics(width: int, height: int, fov_deg: float | None = None, focal_px: float | None = None
               ) -> tuple[Intrinsics, str]:
    """Square pixels and the principal point at the image centre, the focal length from ``focal_px`` or from
    the horizontal field of view ``fov_deg`` (``f = (width / 2) / tan(fov / 2)``), else from
    ``DEFAULT_HFOV_DEG``. Returns the intrinsics and where the focal length came from, in words."""
    if fov_deg is not None and focal_px is not None:
        raise CameraInputError("give --fov or --focal, not both")
    if focal_px is not None:
        if not (math.isfinite(focal_px) and 1.0 <= focal_px <= 1e6):
            raise CameraInputError(f"--focal {focal_px}: must be a focal length in [1, 1e6] pixels")
        f, source = float(focal_px), f"--focal {focal_px:g} px"
    else:
        fov = DEFAULT_HFOV_DEG if fov_deg is None else fov_deg
        if not (math.isfinite(fov) and 1.0 <= fov <= 170.0):
            raise CameraInputError(f"--fov {fov_deg}: must be a horizontal field of view in [1, 170] degrees")
        f = 0.5 * width / math.tan(math.radians(0.5 * fov))
        source = (f"--fov {fov:g} deg" if fov_deg is not None else
                  f"the default horizontal field of view, {DEFAULT_HFOV_DEG:g} deg")
        source += f" (focal {f:.0f} px)"
    return Intrinsics(int(width), int(height), f, f, 0.5 * width, 0.5 * height), source


def gravity(elevation_deg: float, n_frames: int) -> np.ndarray:
    """The unit gravity vector in the camera frame (OpenCV: x right, y down, z forward) of a camera without roll
    pitched ``elevation_deg`` down, ``(n_frames, 3)``: ``(0, cos e, sin e)``."""
    if not (math.isfinite(elevation_deg) and -89.0 <= elevation_deg <= 89.0):
        raise CameraInputError(f"--elevation {elevation_deg}: must be in [-89, 89] degrees (positive looks down)")
    e = math.radians(elevation_deg)
    return np.tile([0.0, math.cos(e), math.sin(e)], (n_frames, 1))


def person_observation(track: PersonTrack, fps: float, intr: Intrinsics, elevation_deg: float | None
                       ) -> Observation:
    """One person's flows over frames ``track.first..track.last`` as the engine's observation."""
    flows = track.frame_flows()
    g = None if elevation_deg is None else gravity(elevation_deg, len(flows))
    return Observation(fps, intr, flows, gravity=g).validate()


def default_database(fps: float):
    """The procedural database of the default recipe at ``fps``: ``DEFAULT_STATES`` states per side, or fewer
    when the shortest demonstration at this frame rate has fewer frames (an HMM state needs a frame; at 10 fps
    the shortest run is 9 frames). Takes a few seconds."""
    from harness.engine import MotionDatabase
    from harness.motion.performer import CLASSES, CYCLIC, training_set

    motions = training_set(CLASSES, DEFAULT_DEMOS, DEFAULT_SEED, float(fps))
    states = min(DEFAULT_STATES, min(m.n_frames for m in motions))
    if states < 2:
        raise HarnessError(f"at {fps:g} fps a demonstration has {states} frames: too few for a motion database")
    return MotionDatabase(n_states=states, cyclic=CYCLIC, mirrored=True).fit(motions)


def load_database(path: str, fps: float):
    """A database file from ``harness train-database``, learned at the video's ``fps``."""
    from harness.engine import MotionDatabase
    from harness.errors import EngineError
    from harness.io import inspect_npz

    inspect_npz(path, EngineError, "database", MAX_DATABASE_BYTES)
    db = MotionDatabase.load(path)
    if abs(db.fps_ - fps) > 1e-6:
        raise EngineError(f"--database {path}: learned at {db.fps_:g} fps, the video runs at {fps:g} fps "
                          f"(train one with `harness train-database --fps {fps:g}`)")
    return db


@dataclass(frozen=True)
class Answer:
    """What the engine answered for one person: the class at the last frame and its posterior, the top three
    ``(class, posterior)``, and the wall time (s) the engine took."""

    answer: str
    confidence: float
    top: tuple[tuple[str, float], ...]
    seconds: float


def summarise(est, seconds: float) -> Answer:
    """The engine's ``Estimate`` in a line: the last frame's class posterior, best first."""
    post = est.class_posterior[-1]
    order = np.argsort(-post, kind="stable")[:3]
    top = tuple((str(est.classes[i]), float(post[i])) for i in order)
    return Answer(top[0][0], top[0][1], top, seconds)
