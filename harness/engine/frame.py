"""One frame's input to the engine, built once per frame: the only thing a stage receives besides its own state.

A ``Frame`` holds what the camera gave for frame ``index`` (the flows, the camera's own motion, the optional
camera prior) and what the sequence fixes (intrinsics, frame rate), plus the open region: where flows have
appeared recently (``open_region``; the basis of negative evidence). ``Frames`` builds them in order from
per-frame inputs, keeping the open region's memory between frames.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from harness.engine.config import LikelihoodSettings
from harness.engine.open_region import OpenMask, OpenRegion
from harness.errors import EngineError
from harness.observation import Observation
from harness.pinhole import Intrinsics


@dataclass(frozen=True)
class Frame:
    """The engine's input at frame ``index``.

    flows: ``(M, 4)`` ``(u, v, du, dv)`` pixels and pixels/s; camera_motion: ``(6,)`` the camera's linear (m/s)
    and angular (rad/s) velocity in its own frame, or None (static); gravity: ``(3,)`` unit vector in the camera
    frame, or None; camera_height: metres above the floor, or None; open: the open region now, or None (negative
    evidence off); posture: the bottom-up estimate of the window of flows ending here
    (``bottom_up.PostureEstimate``), or None (none made, or too few flows)."""

    index: int
    intr: Intrinsics
    fps: float
    flows: np.ndarray
    camera_motion: np.ndarray | None = None
    gravity: np.ndarray | None = None
    camera_height: float | None = None
    open: OpenMask | None = None
    posture: object | None = None

    @property
    def dt(self) -> float:
        return 1.0 / self.fps

    @property
    def has_flows(self) -> bool:
        return len(self.flows) > 0


class Frames:
    """Builds a sequence's frames in order (state: the open region's memory and the frame count)."""

    def __init__(self, intr: Intrinsics, fps: float, settings: LikelihoodSettings, camera_moves: bool = False):
        if not fps > 0:
            raise EngineError(f"fps must be positive, got {fps}")
        self.intr, self.fps = intr, float(fps)
        self._count = 0
        if settings.open_memory_s < 0:
            self._region = None
        else:
            # A moving camera sees a new image every frame: only the current frame's flows mark it open.
            memory = 0 if camera_moves else int(round(settings.open_memory_s * self.fps))
            self._region = OpenRegion(intr.width, intr.height, settings.open_cell_px, memory)

    def next(self, flows: np.ndarray, camera_motion: np.ndarray | None = None, gravity: np.ndarray | None = None,
             camera_height: float | None = None) -> Frame:
        """The next frame, from its flows ``(M, 4)`` and the optional camera motion and prior."""
        flows = np.asarray(flows, dtype=float).reshape(-1, 4)
        if camera_height is not None and gravity is None:
            raise EngineError(f"frame {self._count}: a camera height needs gravity (the floor's normal)")
        mask = None if self._region is None else self._region.update(flows)
        frame = Frame(self._count, self.intr, self.fps, flows,
                      None if camera_motion is None else np.asarray(camera_motion, dtype=float),
                      None if gravity is None else np.asarray(gravity, dtype=float),
                      None if camera_height is None else float(camera_height), mask)
        self._count += 1
        return frame


def observation_frames(obs: Observation, settings: LikelihoodSettings) -> Iterator[Frame]:
    """The frames of a recorded observation, in order."""
    frames = Frames(obs.intrinsics, obs.fps, settings, camera_moves=obs.camera_motion is not None)
    for t, flows in enumerate(obs.flows):
        yield frames.next(flows, None if obs.camera_motion is None else obs.camera_motion[t],
                          None if obs.gravity is None else obs.gravity[t],
                          None if obs.camera_height is None else obs.camera_height[t])
