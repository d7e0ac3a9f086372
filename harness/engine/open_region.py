"""Where the image has shown flows recently: the region obstacles leave open.

The engine does not know the scene. It only knows where flows have appeared: a body part predicted where flows
appeared a moment ago, and where none appear now, is not hidden by a static obstacle, so the hypothesis that
predicts it should pay for the missing flows (negative evidence). A part predicted where no flow has appeared
for a while may be behind something the engine cannot see, and its mixture weight may adapt (see
``likelihood``). The map is a grid of ``cell`` pixels; a cell is open while a flow fell in it or its eight
neighbours within the last ``memory`` frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter


def _cells(pix: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid rows and columns of pixels ``(..., 2)`` (NaN and infinities land outside the grid)."""
    cells = np.floor(np.nan_to_num(np.asarray(pix, dtype=float) / cell, nan=-1.0, posinf=-1.0,
                                   neginf=-1.0)).astype(int)
    return cells[..., 1], cells[..., 0]


@dataclass(frozen=True)
class OpenMask:
    """The open region at one frame: ``open`` ``(rows, cols)`` bool over a grid of ``cell`` pixels."""

    open: np.ndarray
    cell: float

    def held(self, pix: np.ndarray) -> np.ndarray:
        """Whether pixels ``(..., 2)`` lie in the open region (outside the image: not)."""
        rows, cols = _cells(pix, self.cell)
        shape = self.open.shape
        inside = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
        out = np.zeros(rows.shape, dtype=bool)
        out[inside] = self.open[rows[inside], cols[inside]]
        return out


class OpenRegion:
    """The recently seen part of a ``width`` x ``height`` image (state: the frame each cell last saw a flow)."""

    def __init__(self, width: int, height: int, cell: float, memory: int):
        self.cell = float(cell)
        self.memory = int(memory)
        self.shape = (int(np.ceil(height / cell)), int(np.ceil(width / cell)))
        self._last = np.full(self.shape, -np.inf)
        self._frame = -1

    def update(self, flows: np.ndarray) -> OpenMask:
        """Add one frame's flows ``(M, >= 2)`` (pixel positions first); returns the open region now."""
        self._frame += 1
        if len(flows):
            rows, cols = _cells(np.asarray(flows, dtype=float)[:, :2], self.cell)
            inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
            self._last[rows[inside], cols[inside]] = self._frame
        return OpenMask(maximum_filter(self._last >= self._frame - self.memory, size=3), self.cell)
