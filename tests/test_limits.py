"""The stated limits of one run: the bound on a procedural demonstration's length holds for every class, and
every shipped scenario is well inside the frame and memory limits."""

from pathlib import Path

import numpy as np
import pytest

from harness.engine import TrackerConfig
from harness.evaluation import limits
from harness.evaluation.loading import load_scenario, parse_scenario
from harness.evaluation.sweep import conditions
from harness.motion.performer import CLASSES, demonstrations

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


@pytest.mark.parametrize("label", CLASSES)
def test_no_procedural_demonstration_outlasts_the_bound(label):
    for seed in range(3):
        for m in demonstrations(label, 4, np.random.default_rng(seed), subject=1000 + seed):
            assert m.duration < 0.8 * limits.PRIMITIVE_S_BOUND, (label, m.duration)


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_scenarios_are_well_inside_the_limits(path):
    for cond in conditions(load_scenario(path)):
        frames = limits.run_frames(cond.config)
        assert frames is None or frames < limits.MAX_RUN_FRAMES / 5
        assert sum(limits.run_bytes(cond.config).values()) < limits.MAX_RUN_BYTES / 3


def test_the_estimate_grows_with_what_a_run_allocates():
    base = sum(limits.run_bytes(parse_scenario({"name": "b"})).values())
    doubled = {"tracks": {"particles": 2 * TrackerConfig().tracks.particles}}
    engine = limits.run_bytes(parse_scenario({"name": "e", "engine": doubled}))["engine"]
    assert engine == pytest.approx(2 * limits.run_bytes(parse_scenario({"name": "b"}))["engine"], rel=0.01)
    rendered = sum(limits.run_bytes(parse_scenario({"name": "r", "observation": {"mode": "rendered"}})).values())
    assert rendered - base == limits.RENDER_PIXEL_BYTES * 640 * 480
