from pathlib import Path

import numpy as np
import pytest

from harness.body import BodyModel

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
MOCAP_DIR = SHARED / "mocap" / "cmu"


@pytest.fixture(scope="session")
def body() -> BodyModel:
    return BodyModel.load()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261123)


def require_mocap() -> Path:
    """The sample CMU captures, or a skip that says where they were looked for."""
    if not (MOCAP_DIR / "MANIFEST.csv").is_file():
        pytest.skip(f"sample captures not found at {MOCAP_DIR} (the ../shared checkout is absent)")
    return MOCAP_DIR


@pytest.fixture(scope="module")
def trained(body):
    """The engine tests' small database: the synthetic primitives of ``engine_fixtures``, 4 demonstrations each,
    6 states (a module may define its own ``trained``)."""
    from engine_fixtures import CLASSES, synthetic_demos
    from harness.engine import MotionDatabase

    rng = np.random.default_rng(1)
    train = [m for c in CLASSES for m in synthetic_demos(body, c, 4, rng)]
    return MotionDatabase(n_states=6, cyclic=("march", "wave"), n_iter=5).fit(train)
