"""The open region: where flows appeared within the memory, one cell of margin around them."""

import numpy as np

from harness.engine.open_region import OpenRegion


def test_cells_stay_open_for_the_memory_then_close():
    region = OpenRegion(160, 120, 16.0, memory=2)
    mask = region.update(np.array([[40.0, 40.0, 0.0, 0.0]]))          # cell (2, 2)
    pix = np.array([[40.0, 40.0], [56.0, 56.0], [72.0, 40.0], [-5.0, 40.0], [np.nan, 1.0]])
    # The cell itself and its eight neighbours; two cells away, outside the image, or NaN: not.
    assert mask.held(pix).tolist() == [True, True, False, False, False]
    region.update(np.empty((0, 4)))
    assert region.update(np.empty((0, 4))).held(pix[:1]).tolist() == [True]     # seen two frames ago: still open
    assert region.update(np.empty((0, 4))).held(pix[:1]).tolist() == [False]    # three frames ago: beyond memory
    assert mask.held(pix[:1]).tolist() == [True]           # a frame's mask is a snapshot: later frames leave it
    # Flows outside the image are ignored rather than wrapped around.
    mask = region.update(np.array([[-30.0, 500.0, 0.0, 0.0]]))
    assert not mask.held(np.array([[0.0, 0.0], [159.0, 119.0]])).any()
