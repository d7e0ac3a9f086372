"""Reading a scenario: the file, the schema's validation with errors that name the key path, and the checks of
the whole plan before any run.

Every error names the file, the key path and what was expected, for example::

    default.yaml: camera.distnce: unknown key
    default.yaml: sweep['markers.count']: empty list (give at least one value)
    default.yaml: database.classes[3]: unknown class 'wlak' (valid: bow, jump, ...)
    default.yaml: engine.particles: moved to engine.tracks.particles

Checked at load, before any database is trained or file written: every condition of the grid as written
(``sweep``), the method names against the registry (``harness.evaluation.methods``; none listed: its
default) or imported from outside (``harness.evaluation.external``, their versions stamped on the scenario), the
plan's size, where the camera would stand, and each run's memory (``limits``).
"""

from __future__ import annotations

import itertools
import re
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from harness import safe_yaml
from harness.evaluation.limits import LimitError, check_run
from harness.evaluation.external import versions
from harness.evaluation.methods import MethodError, default_methods
from harness.evaluation.scenario import MAX_RUNS, RANDOM, Scenario, ScenarioError, scene_spec, short, to_spec
from harness.evaluation.sweep import Condition, apply, check_sweep_shape, conditions
from harness.scene.spec import CameraSpec, OccluderSpec, SceneError, SubjectSpec

MAX_SCENARIO_BYTES = 1_000_000

def _format_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _message(err: dict) -> str:
    kind, msg = err["type"], err["msg"]
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "missing":
        return "required key is missing"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    got = err.get("input")
    if kind not in ("value_error",) and not isinstance(got, (dict, list)):
        msg += f" (got {short(got)})"
    return msg


_UNION_TAG = re.compile(r"^(int|float|str|bool|none|literal\[.*\]|tuple\[.*\]|list\[.*\]|.*Section)$")


def _strip(loc: tuple) -> tuple:
    """Drop pydantic's union-member tags (``float``, ``literal['random']``) so the path is the user's key."""
    return tuple(p for p in loc if not (isinstance(p, str) and (_UNION_TAG.match(p) or p.startswith("function"))))


def first_error(exc: ValidationError) -> tuple[str, str]:
    errors = exc.errors()
    loc = _strip(errors[0]["loc"])
    same = [e for e in errors if _strip(e["loc"]) == loc]
    path = _format_loc(loc)
    if len(same) > 1:   # a union: every alternative failed; say what each expected
        got = same[0].get("input")
        expected = " or ".join(dict.fromkeys(_message(e).split(" (got ")[0] for e in same))
        return path, f"{expected} (got {short(got)})"
    msg = _message(errors[0])
    # Validator messages may start with their own key path ("classes[3]: ...", "[1]: ...").
    if errors[0]["type"] == "value_error" and ":" in msg:
        head = msg.split(":", 1)[0]
        if head and " " not in head:
            joined = head if not path else (f"{path}{head}" if head.startswith("[") else f"{path}.{head}")
            return joined, msg.split(":", 1)[1].strip()
    return path, msg


def _validate(raw: dict, where: str) -> Scenario:
    try:
        return Scenario.model_validate(raw)
    except ValidationError as exc:
        path, msg = first_error(exc)
        n_keys = len({_strip(e["loc"]) for e in exc.errors()})
        extra = f" (and {n_keys - 1} more)" if n_keys > 1 else ""
        raise ScenarioError(f"{where}: {path}: {msg}{extra}" if path else f"{where}: {msg}{extra}") from None


def _under(path: str, key: str) -> bool:
    return path == key or path.startswith(key + ".") or path.startswith(key + "[")


def _check_conditions(raw: dict, sweep: dict, where: str) -> list[Scenario]:
    """Every condition of the grid validated as written (the base with the condition's values), so that rules
    between fields hold for each condition and not for the unswept base. An error in a swept value names the
    value (``sweep['markers.count'][1]: ...``); one that holds for some conditions only names the first;
    one of the base in every condition is the base's."""
    keys = list(sweep)
    combos = list(itertools.product(*(range(len(sweep[k])) for k in keys)))
    out = []
    for c, combo in enumerate(combos):
        values = [(k, sweep[k][i]) for k, i in zip(keys, combo)]
        try:
            out.append(Scenario.model_validate(apply(raw, values, where)))
            continue
        except ValidationError as exc:
            path, msg = first_error(exc)
        for k, i in zip(keys, combo):
            if _under(path, k):
                rest = path[len(k):].lstrip(".")
                raise ScenarioError(f"{where}: sweep[{k!r}][{i}]: {rest + ': ' if rest else ''}{msg}") from None
        everywhere = True
        for other in combos:
            try:
                Scenario.model_validate(apply(raw, [(k, sweep[k][i]) for k, i in zip(keys, other)], where))
                everywhere = False
                break
            except ValidationError as again:
                if first_error(again) != (path, msg):
                    everywhere = False
                    break
        label = "" if everywhere else f" (condition {_label(values)})"
        raise ScenarioError(f"{where}: {path}: {msg}{label}" if path else f"{where}: {msg}{label}")
    return out


def _label(values) -> str:
    return ",".join(f"{k}={v}" for k, v in values) or "base"


def _runs_per_condition(cfg: Scenario) -> int | None:
    """Test motions of a condition when known at load (procedural and streams; captures: after resolving)."""
    if cfg.test.stream is not None:
        return len(cfg.test.stream.takes) if cfg.test.stream.takes is not None else cfg.test.stream.count
    if cfg.test.motions == "procedural":
        return len(cfg.classes) * cfg.test.demos_per_class
    return None


def _check_size(configs: list[Scenario], where: str) -> None:
    """Refuse a plan of more than MAX_RUNS runs before building it (a huge sweep or repeat count would hang)."""
    n = sum(cfg.repeats * (_runs_per_condition(cfg) or 1) for cfg in configs)
    if n > MAX_RUNS:
        raise ScenarioError(f"{where}: the plan has {n} runs ({len(configs)} conditions x repeats x test motions), "
                            f"more than {MAX_RUNS}: reduce repeats or the sweep")


def _check_methods(cond: Condition, where: str) -> dict[str, str]:
    """Every listed method is built in (``harness.evaluation.methods``), ``module:function`` or installed, and can
    be imported (``harness.evaluation.external``); returns the versions of those from outside the package."""
    out = {}
    for i, m in enumerate(cond.config.methods):
        try:
            out |= versions([m])
        except MethodError as exc:
            label = "" if cond.label == "base" else f" (condition {cond.label})"
            raise ScenarioError(f"{where}: methods[{i}]: {exc}{label}") from None
    return out


def _check_limits(cond: Condition, where: str) -> None:
    try:
        check_run(cond.config)
    except LimitError as exc:
        label = "" if cond.label == "base" else f" (condition {cond.label})"
        raise ScenarioError(f"{where}: {exc.key}: {exc}{label}") from None


@lru_cache(maxsize=256)
def _placement_error(cam: CameraSpec, occ: OccluderSpec, subject: SubjectSpec, every_azimuth: bool):
    """``(key, why)`` of a camera that would stand where it cannot, or None (cached: a sweep's conditions share
    their camera and obstacles)."""
    from harness.scene.placement import check_camera_placement, check_obstacles_clear

    azimuths = np.arange(0.0, 360.0, 1.0) if every_azimuth else np.array([float(cam.azimuth)])
    try:
        check_obstacles_clear(occ, subject)
        check_camera_placement(cam, occ, subject, azimuths)
    except SceneError as exc:
        return exc.key, exc.why
    return None


def _check_scene(cond: Condition, where: str) -> None:
    """The rules between the scene's parts (``SceneSpec``), for each condition: a sweep may combine values that
    each pass alone (``observation.mode: video`` with a swept ``camera.motion``). The per-run draws are
    irrelevant to those rules, so any generator serves."""
    try:
        scene_spec(cond.config, np.random.default_rng(0))
    except SceneError as exc:
        label = "" if cond.label == "base" else f" (condition {cond.label})"
        raise ScenarioError(f"{where}: {exc.key}: {exc.why}{label}") from None


def _check_placement(cond: Condition, where: str) -> None:
    """Where the camera would stand, for every azimuth it can take, and whether an obstacle given by hand
    encloses the subject (decidable cases only; see ``harness.scene.placement``)."""
    cfg = cond.config
    cam = cfg.camera
    every = cam.azimuth == RANDOM or (cam.motion == "orbit" and cam.orbit_rate != 0.0)
    error = _placement_error(to_spec(cam), to_spec(cfg.occluders), to_spec(cfg.subject), every)
    if error is not None:
        label = "" if cond.label == "base" else f" (condition {cond.label})"
        raise ScenarioError(f"{where}: {error[0]}: {error[1]}{label}")


def parse_scenario(raw: Any, where: str = "<scenario>") -> Scenario:
    """Validate a scenario given as a mapping (``where`` names its source in errors).

    With a sweep, the returned scenario's sections hold the first condition's values (the base with every
    swept key at its first value) and ``sweep`` the grid: the unswept value of a swept key is never used, so
    it need not be valid with the rest (``occluders.amount: 0.4`` beside a swept preset)."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where}: a scenario must be a mapping of keys to values, got {type(raw).__name__}")
    sweep = raw.get("sweep")
    if sweep is not None and not isinstance(sweep, dict):
        raise ScenarioError(f"{where}: sweep: must map dotted keys to lists of values, got {short(sweep)}")
    for key, values in (sweep or {}).items():
        if not isinstance(key, str):
            raise ScenarioError(f"{where}: sweep: keys must be dotted names, got {short(key)}")
        if not isinstance(values, list):
            raise ScenarioError(f"{where}: sweep[{key!r}]: must be a list of values, got {short(values)}")
    sweep = sweep or {}
    # The outside methods' versions are the harness's own stamp, always taken from the code (a stored
    # scenario.json read again, by run-video, carries the stamps of when it was stored).
    raw = {k: v for k, v in raw.items() if k != "method_versions"}
    if "methods" not in raw:
        raw = raw | {"methods": list(default_methods())}
    if not sweep:
        scenario = _validate(raw, where)
    else:
        check_sweep_shape(sweep, where)
        first = apply(raw, [(k, v[0]) for k, v in sweep.items()], where)
        _check_conditions(raw, sweep, where)
        scenario = _validate(first | {"sweep": sweep}, where)
    conds = conditions(scenario)
    _check_size([c.config for c in conds], where)
    stamped: dict[str, str] = {}
    for cond in conds:
        stamped |= _check_methods(cond, where)
        _check_scene(cond, where)
        _check_placement(cond, where)
        _check_limits(cond, where)
    return scenario.model_copy(update={"method_versions": dict(sorted(stamped.items()))}) if stamped else scenario


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; ``ScenarioError`` names the file and the key path. The file's
    size and kind are checked before it is read, and the YAML is read with ``harness.safe_yaml`` (aliases
    bounded, duplicate keys and oversized integers refused)."""
    raw = safe_yaml.load(path, ScenarioError, "scenario", MAX_SCENARIO_BYTES)
    return parse_scenario(raw if raw is not None else {}, str(path))
