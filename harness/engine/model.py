"""What the engine knows before it sees anything: the database, the body, its own model points, and every
database state's output distribution carried to those points (computed once, shared by every track and run)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.body.model import BodyModel
from harness.body.surface import SurfacePoints, even_surface
from harness.engine.database import MotionDatabase
from harness.engine.transform import PointDistributions, database_point_distributions, patch_std


@dataclass(frozen=True)
class EngineModel:
    """The database in the body frame, ready for the image.

    points: the engine's own sample of the body surface, spread evenly by area (``even_surface``; seeded
    independently of any marker);
    spread: the per-axis std of the surface patch one point stands for (m); dists: every state's point
    distributions, flattened to ``S = C * K`` in (class, state) order; db_means, db_covars: ``(S, 106)``;
    body_extent: the vertical extent (m) of the model points that ``particle_filter.depth_guess`` compares the
    flows' with: the 5-95% percentile range of their height, the median over the database's states (the
    standing height would put the body 1.3x too far, issue 21). Read-only after construction.
    """

    db: MotionDatabase
    body: BodyModel
    points: SurfacePoints
    spread: float
    dists: PointDistributions
    db_means: np.ndarray
    db_covars: np.ndarray
    body_extent: float

    @classmethod
    def build(cls, db: MotionDatabase, body: BodyModel, model_points: int, model_seed: int) -> "EngineModel":
        db.validate()
        points = even_surface(body, model_points, np.random.default_rng(model_seed))
        spread = patch_std(body, model_points)
        C, K, D = db.means_.shape
        dists = database_point_distributions(db, body, points, spread)
        return cls(db, body, points, spread, dists, db.means_.reshape(C * K, D), db.covars_.reshape(C * K, D),
                   body_extent(dists))

    @property
    def n_classes(self) -> int:
        return self.db.means_.shape[0]

    @property
    def n_states(self) -> int:
        """States per primitive: every chain's (twice the database's ``n_states`` when it is both-handed)."""
        return self.db.means_.shape[1]


def body_extent(dists: PointDistributions) -> float:
    """The median over states ``(S, P, 3)`` of the 5-95% range of the model points' mean height (base frame z,
    the body's up): the statistic ``particle_filter.depth_guess`` takes of the flows, so the guess is unbiased
    for an unoccluded body."""
    lo, hi = np.percentile(dists.pos[:, :, 2], [5, 95], axis=1)
    return float(np.median(hi - lo))
