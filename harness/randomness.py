"""Named random generators: one ``numpy.random.Generator`` per (seed, purpose), independent of each other, so
that drawing more numbers for one purpose (a new method, a longer motion) never shifts another's numbers."""

from __future__ import annotations

import numpy as np


def named_generator(seed: int, name: str) -> np.random.Generator:
    """The generator of ``SeedSequence([seed, *bytes of name])``: e.g. ``named_generator(run_seed, "scene")``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), *name.encode()]))
