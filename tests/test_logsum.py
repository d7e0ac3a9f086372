"""The engine's logsumexp against scipy's."""

import numpy as np
from scipy.special import logsumexp as reference

from harness.engine.logsum import logsumexp


def test_logsumexp_equals_scipy_including_infinities(rng):
    x = rng.normal(0, 300, (4, 5, 6))
    x[0, 0, :] = -np.inf
    for axis in (None, 0, 1, 2):
        np.testing.assert_allclose(logsumexp(x, axis=axis), reference(x, axis=axis), rtol=1e-12)
    assert logsumexp(np.array([-np.inf, -np.inf])) == -np.inf
    assert isinstance(logsumexp(x), float)
