"""Where the image has shown flows recently: the region obstacles leave open.

The engine does not know the scene. It only knows where flows have appeared: a body part predicted where flows
appeared a moment ago, and where none appear now, is not hidden by a static obstacle, so the hypothesis that
predicts it should pay for the missing flows (negative evidence). A part predicted where no flow has appeared
for a while may be behind something the engine cannot see, and its mixture weight may adapt (see
``likelihood``). The map is a grid of ``cell`` pixels; a cell is open while a flow fell in it or its eight
neighbours within the last ``memory`` frames.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter


class OpenRegion:
    """The recently seen part of a ``width`` x ``height`` image (state: the frame each cell last saw a flow)."""

    def __init__(self, width: int, height: int, cell: float, memory: int):
        self.cell = float(cell)
        self.memory = int(memory)
        self.shape = (int(np.ceil(height / cell)), int(np.ceil(width / cell)))
        self._last = np.full(self.shape, -np.inf)
        self._frame = -1
        self._open = np.zeros(self.shape, dtype=bool)

    def update(self, flows: np.ndarray) -> None:
        """Add one frame's flows ``(M, >= 2)`` (pixel positions first)."""
        self._frame += 1
        if len(flows):
            rows, cols = self._cells(np.asarray(flows, dtype=float)[:, :2])
            inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
            self._last[rows[inside], cols[inside]] = self._frame
        self._open = maximum_filter(self._last >= self._frame - self.memory, size=3)

    def held(self, pix: np.ndarray) -> np.ndarray:
        """Whether pixels ``(..., 2)`` lie in the open region (outside the image: not)."""
        rows, cols = self._cells(pix)
        inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
        out = np.zeros(rows.shape, dtype=bool)
        out[inside] = self._open[rows[inside], cols[inside]]
        return out

    def _cells(self, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cells = np.floor(np.nan_to_num(np.asarray(pix, dtype=float) / self.cell, nan=-1.0, posinf=-1.0,
                                       neginf=-1.0)).astype(int)
        return cells[..., 1], cells[..., 0]
