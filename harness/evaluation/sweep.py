"""The sweep grid: a scenario's ``sweep`` maps dotted keys to lists of values; their Cartesian product is the
conditions, each the scenario with its values applied (``conditions``, last key fastest). Which keys a sweep may
take (``sweepable_keys``: every key of the schema's sections, the engine's as ``engine.<section>.<field>``, but
those in ``UNSWEEPABLE``) and the grid's shape are checked before any value is validated
(``check_sweep_shape``)."""

from __future__ import annotations

import copy
import itertools
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from harness.engine.config import TrackerConfig
from harness.evaluation.limits import MAX_CONDITIONS, MAX_SWEEP_VALUES
from harness.evaluation.scenario import Scenario, ScenarioError, short
from harness.settings import unknown_key

# Keys a sweep may not take: the capture set is resolved once per scenario (its directory, manifest and classes
# are checked at load), and the scenario seed is what every condition's draws derive from (conditions share
# their draws by design, and a swept value would collide with the run's `seed` column): repeats give
# independent draws.
UNSWEEPABLE = {"seed": "the scenario seed is shared by every condition (common random numbers); raise repeats for "
                       "independent draws",
               "database.capture_sets": "capture sets are resolved once per scenario",
               "database.capture_dirs": "capture sets are resolved once per scenario",
               "database.manifest": "capture sets are resolved once per scenario",
               "method_versions": "stamped from the methods' code at load, not written in a scenario"}


def set_dotted(raw: dict, key: str, value: Any, where: str = "<scenario>") -> dict:
    """A copy of ``raw`` (its ``sweep`` left out) with the dotted ``key`` set to ``value``."""
    out = copy.deepcopy({k: v for k, v in raw.items() if k != "sweep"})
    node = out
    parts = key.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ScenarioError(f"{where}: sweep[{key!r}]: {p} is not a section")
    node[parts[-1]] = value
    return out


def apply(raw: dict, values: Iterable[tuple[str, Any]], where: str) -> dict:
    """A copy of ``raw`` (its ``sweep`` left out) with every dotted key of ``values`` set."""
    out = {k: v for k, v in raw.items() if k != "sweep"}
    for k, v in values:
        out = set_dotted(out, k, v, where)
    return out


def _keys(model: type[BaseModel], prefix: str) -> list[str]:
    """The dotted keys of a schema model: a nested section's keys under its name (``engine.tracks.particles``)."""
    keys = []
    for name, field in model.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            keys += _keys(ann, f"{prefix}{name}.")
        else:
            keys.append(prefix + name)
    return keys


def sweepable_keys() -> list[str]:
    """Every dotted key a sweep may take."""
    return [k for k in _keys(Scenario, "") if k not in UNSWEEPABLE and k not in ("name", "sweep")]


def check_sweep_shape(sweep: dict, where: str) -> None:
    """Keys, list sizes, repeated values and the grid's size, before any value is validated (a grid of
    millions of conditions is refused at once, not after validating each)."""
    valid = sweepable_keys()
    for key, values in sweep.items():
        if key in UNSWEEPABLE:
            raise ScenarioError(f"{where}: sweep[{key!r}]: not sweepable: {UNSWEEPABLE[key]}")
        if key not in valid:
            section, _, name = key.partition(".")
            moved = unknown_key(TrackerConfig, name, "setting") if section == "engine" else ""
            if " moved to " in moved:
                raise ScenarioError(f"{where}: sweep[{key!r}]: moved to engine.{moved.split(' moved to ')[1]}")
            raise ScenarioError(f"{where}: sweep[{key!r}]: unknown key (valid: {', '.join(valid)})")
        if len(values) == 0:
            raise ScenarioError(f"{where}: sweep[{key!r}]: empty list (give at least one value)")
        if len(values) > MAX_SWEEP_VALUES:
            raise ScenarioError(f"{where}: sweep[{key!r}]: {len(values)} values, more than {MAX_SWEEP_VALUES}")
    n = math.prod(len(v) for v in sweep.values())
    if n > MAX_CONDITIONS:
        sizes = " x ".join(str(len(v)) for v in sweep.values())
        raise ScenarioError(f"{where}: sweep: {sizes} = {n} conditions, more than {MAX_CONDITIONS}")
    for key, values in sweep.items():
        try:
            texts = [json.dumps(v, sort_keys=True) for v in values]
        except (TypeError, ValueError):
            raise ScenarioError(f"{where}: sweep[{key!r}]: values must be numbers, strings, lists or mappings "
                                f"({short(values)})") from None
        if len(set(texts)) != len(texts):
            raise ScenarioError(f"{where}: sweep[{key!r}]: a value is listed twice ({short(values)})")


@dataclass(frozen=True)
class Condition:
    """One point of the sweep grid: its index, the swept values (dotted key -> value), and the resolved scenario
    (``sweep`` emptied, swept values applied)."""

    index: int
    values: tuple[tuple[str, Any], ...]
    config: Scenario

    @property
    def label(self) -> str:
        """``markers.count=20,occluders.amount=0.2`` (``base`` when nothing is swept)."""
        return ",".join(f"{k}={v}" for k, v in self.values) or "base"


def conditions(scenario: Scenario) -> list[Condition]:
    """The Cartesian product of the sweep, in the order the keys and values are written (last key fastest)."""
    base = scenario.model_dump(mode="json")
    keys = list(scenario.sweep)
    out = []
    for i, combo in enumerate(itertools.product(*(scenario.sweep[k] for k in keys))):
        raw = apply(base, zip(keys, combo), scenario.name)
        out.append(Condition(i, tuple(zip(keys, combo)), Scenario.model_validate(raw)))
    return out
