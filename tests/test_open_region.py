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


def test_the_margin_is_scipys_three_by_three_maximum_filter():
    """The open cells are the recent ones dilated by one cell, as ``scipy.ndimage.maximum_filter`` of size 3
    computes it (its border mode reflects, which for a maximum ignores the outside), on random grids."""
    from scipy.ndimage import maximum_filter

    from harness.engine.open_region import _dilated

    rng = np.random.default_rng(4)
    for shape in [(1, 1), (1, 7), (6, 1), (30, 40)]:
        last = np.where(rng.random(shape) < 0.1, rng.integers(0, 10, shape), -np.inf)
        for since in (0, 5, 9, 10):
            np.testing.assert_array_equal(_dilated(last, since), maximum_filter(last >= since, size=3))
