"""Evaluation scenarios: the YAML schema, its validation, and the sweep grid.

A scenario fixes everything one evaluation needs (database, test split, subject, markers, camera, occluders,
observation noise, engine settings, methods, repeats, seed) plus ``sweep``: a mapping of dotted keys to lists
of values whose Cartesian product gives the *conditions*. Every section forbids unknown keys, and every error
names the key path and what was expected, for example::

    default.yaml: camera.distnce: unknown key
    default.yaml: sweep['markers.count']: empty list (give at least one value)
    default.yaml: database.classes[3]: unknown class 'wlak' (valid: bow, jump, ...)

One schema: the ``markers``, ``camera``, ``occluders``, ``observation`` and ``subject`` sections are generated
from the scene's own spec types (``harness.scene.spec``: the same fields, defaults and checks; a seed or the
azimuth may be left to each run), and ``engine`` from ``harness.engine.TrackerConfig`` (every field by name;
a value is checked by building the ``TrackerConfig``). Everything is checked at load, before any run: also
where the camera would stand (below the floor, inside the standing subject or inside an obstacle given by
hand) and the size of the plan. The schema table in ``docs/evaluation.md`` is ``schema_markdown()``.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
import math
import os
import re
import typing
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model, field_validator, model_validator

from harness import safe_yaml
from harness.engine import TrackerConfig
from harness.errors import EngineError, HarnessError
from harness.evaluation.limits import MAX_CONDITIONS, MAX_SWEEP_VALUES, LimitError, check_run
from harness.evaluation.methods import default_methods, method_names
from harness.motion.performer import CLASSES as PROCEDURAL_CLASSES
from harness.scene.spec import (CameraSpec, MarkerSpec, ObservationSpec, OccluderGeom, OccluderSpec, SceneError,
                                SceneSpec, SubjectSpec)
from harness.version import code_version

MOCAP_ENV = "HARNESS_MOCAP_DIR"
MAX_RUNS = 100_000          # a plan beyond this is refused at load (at seconds per run it would take weeks)
MAX_SCENARIO_BYTES = 1_000_000
MAX_STREAM_PRIMITIVES = 20      # primitives per procedural test stream
MAX_TRANSITION_S = 10.0
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
RESERVED_NAMES = ("cache", "baseline")   # --results/cache holds the database cache, results/baseline the
                                         # regression baseline: a scenario of that name would write into them
RANDOM = "random"


class ScenarioError(HarnessError):
    """A scenario file that cannot be read or does not validate; the message names the file and key path."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class DatabaseConfig(_Section):
    """Where the motion database comes from and how it is trained."""

    source: Literal["procedural", "capture"] = "procedural"
    capture_dir: str | None = None          # capture only; else --mocap-dir or $HARNESS_MOCAP_DIR
    manifest: str = "MANIFEST.csv"          # capture only; a path inside capture_dir
    classes: tuple[str, ...] | None = None  # default: all procedural classes / the manifest's classes
    train_demos: int = Field(8, ge=1, le=1000)   # demonstrations per class (procedural)
    states: int = Field(20, ge=2, le=500)   # HMM states per primitive (per side)
    mirrored: bool = True                   # both-handed: each HMM also holds its mirror-image chain
    seed: int = Field(0, ge=0)              # training seed (demo generation and HMM initialisation)
    fps: float = Field(30.0, gt=0, le=1000)  # frames per second of training and test motions
    with_captures: bool = False             # procedural, test.split captures: also train on the capture demos
                                            # of every subject but the test motion's

    @field_validator("manifest")
    @classmethod
    def _manifest_inside(cls, v):
        from harness.motion.captures import relative_path_problem

        problem = relative_path_problem(v)
        if problem:
            raise ValueError(f"{problem} (got {_short(v)})")
        return v

    @model_validator(mode="after")
    def _check_classes(self):
        if self.classes is not None:
            if len(self.classes) == 0:
                raise ValueError("classes: empty list (omit the key for the default classes)")
            if self.source == "procedural":
                for i, c in enumerate(self.classes):
                    if c not in PROCEDURAL_CLASSES:
                        raise ValueError(f"classes[{i}]: unknown class {c!r} (valid: {', '.join(PROCEDURAL_CLASSES)})")
            if len(set(self.classes)) != len(self.classes):
                raise ValueError(f"classes: listed twice: {sorted({c for c in self.classes if self.classes.count(c) > 1})}")
        return self


class StreamConfig(_Section):
    """Test streams instead of single primitives (``harness.motion.stream``): procedural streams of the
    database's classes by held-out subjects, or capture takes whose manifest rows label their frames."""

    count: int = Field(10, ge=1, le=10000)                 # procedural: streams per condition and repeat
    primitives: tuple[int, int] = (3, 6)                   # procedural: primitives per stream, [min, max]
    transition_s: tuple[float, float] = (0.3, 0.6)         # procedural: a transition's length, [min, max] s
    takes: tuple[str, ...] | None = None                   # capture: the takes (file stems) to test

    @model_validator(mode="after")
    def _check(self):
        lo, hi = self.primitives
        if not 2 <= lo <= hi <= MAX_STREAM_PRIMITIVES:
            raise ValueError(f"primitives: must be [min, max] with 2 <= min <= max <= {MAX_STREAM_PRIMITIVES}, got "
                             f"{list(self.primitives)}")
        t_lo, t_hi = self.transition_s
        if not 0 < t_lo <= t_hi <= MAX_TRANSITION_S:
            raise ValueError(f"transition_s: must be [min, max] seconds with 0 < min <= max <= {MAX_TRANSITION_S:g}, "
                             f"got {list(self.transition_s)}")
        if self.takes is not None and not self.takes:
            raise ValueError("takes: empty list")
        return self


class SplitConfig(_Section):
    """Which motions are tested: held-out procedural demos, a split of the capture set, or (``captures``) every
    capture demonstration against a procedural database (sim-to-real); or, with ``stream``, streams of several
    primitives (``docs/streams.md``)."""

    demos_per_class: int = Field(2, ge=1, le=1000)  # procedural: held-out demos per class
    split: Literal["heldout", "captures", "leave_one_out", "cross_subject", "all"] = "heldout"
    stream: StreamConfig | None = None
    # procedural: the share of test performances of every primitive that are left-sided (None: each primitive's
    # calibrated share); the database's demonstrations keep theirs
    left: float | None = Field(None, ge=0.0, le=1.0)


# --- sections generated from the scene's spec types and the engine's TrackerConfig ------------------------

# Fields a scenario may leave to each run: None (a seed drawn from the run's seed) or "random" (an azimuth
# drawn uniformly in [0, 360) per run). For validation the spec is built with a stand-in value.
_PER_RUN: dict[tuple[type, str], tuple[Any, Any, Any]] = {
    (MarkerSpec, "seed"): (int | None, None, 0),
    (OccluderSpec, "seed"): (int | None, None, 0),
    (SubjectSpec, "seed"): (int | None, None, 0),
    (CameraSpec, "azimuth"): (float | Literal["random"], 0.0, 0.0),
}
_SECTION_OF: dict[type, type[BaseModel]] = {}


def _field_default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    raise TypeError(f"{f.name}: a schema field needs a default")


def _spec_key(exc: SceneError) -> str:
    """The field name of a spec error (``camera.distance`` -> ``distance``)."""
    return (exc.key or "").split(".")[-1]


def _section_from_spec(spec_cls: type, name: str) -> type[BaseModel]:
    """A pydantic section with the spec's fields and defaults whose validation builds the spec itself, so that
    the scene's own checks (bounds, finite numbers, names) are the scenario's."""
    hints = typing.get_type_hints(spec_cls)
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(spec_cls):
        if (spec_cls, f.name) in _PER_RUN:
            ann, default, _ = _PER_RUN[(spec_cls, f.name)]
            fields[f.name] = (ann, default)
            continue
        ann = hints[f.name]
        if typing.get_origin(ann) is tuple and typing.get_args(ann)[0] in _SECTION_OF:   # nested spec types
            ann = tuple[_SECTION_OF[typing.get_args(ann)[0]], ...]
        fields[f.name] = (ann, _field_default(f))

    def check(self):
        try:
            to_spec(self, spec_cls)
        except SceneError as exc:
            raise ValueError(f"{_spec_key(exc)}: {exc.why} (got {exc.value!r})") from None
        return self

    model = create_model(name, __base__=_Section, __doc__=spec_cls.__doc__, __module__=__name__,
                         __validators__={"_spec_checks": model_validator(mode="after")(check)}, **fields)
    model.spec_type = spec_cls
    _SECTION_OF[spec_cls] = model
    return model


def to_spec(section: BaseModel, spec_cls: type | None = None, **values: Any):
    """The spec a generated section describes; ``values`` fill the per-run fields (seeds, azimuth), which
    otherwise take their stand-ins."""
    spec_cls = spec_cls or section.spec_type
    kwargs = {}
    for f in dataclasses.fields(spec_cls):
        v = values.get(f.name, getattr(section, f.name))
        if (spec_cls, f.name) in _PER_RUN and (v is None or v == RANDOM):
            v = _PER_RUN[(spec_cls, f.name)][2]
        if isinstance(v, tuple) and v and isinstance(v[0], BaseModel):
            v = tuple(to_spec(item) for item in v)
        kwargs[f.name] = v
    return spec_cls(**kwargs)


OccluderGeomConfig = _section_from_spec(OccluderGeom, "OccluderGeomConfig")
MarkersConfig = _section_from_spec(MarkerSpec, "MarkersConfig")
CameraConfig = _section_from_spec(CameraSpec, "CameraConfig")
OccludersConfig = _section_from_spec(OccluderSpec, "OccludersConfig")
ObservationConfig = _section_from_spec(ObservationSpec, "ObservationConfig")
SubjectConfig = _section_from_spec(SubjectSpec, "SubjectConfig")


def _engine_section() -> type[BaseModel]:
    """Every ``TrackerConfig`` field by name, with its default; validated by building the TrackerConfig."""
    hints = typing.get_type_hints(TrackerConfig)
    fields = {f.name: (hints[f.name], _field_default(f)) for f in dataclasses.fields(TrackerConfig)}

    def check(self):
        values = self.model_dump()
        try:
            TrackerConfig(**values)
        except EngineError as exc:
            # Name the key: the first field that fails on its own (else the message alone, for a rule
            # between fields).
            for name, value in values.items():
                if value == fields[name][1]:
                    continue
                try:
                    TrackerConfig(**{name: value})
                except EngineError:
                    text = str(exc).removeprefix(f"engine setting {name} ")
                    raise ValueError(f"{name}: {text}") from None
            raise ValueError(str(exc)) from None
        return self

    return create_model("EngineConfig", __base__=_Section, __doc__=TrackerConfig.__doc__, __module__=__name__,
                        __validators__={"_tracker_checks": model_validator(mode="after")(check)}, **fields)


EngineConfig = _engine_section()


class Scenario(_Section):
    """A validated scenario; ``sweep`` maps dotted keys to the values each condition takes."""

    name: str = Field(max_length=100)        # also the results directory's name (``_one_component``)
    seed: int = Field(0, ge=0)
    repeats: int = Field(1, ge=1, le=MAX_RUNS)
    database: DatabaseConfig = DatabaseConfig()
    test: SplitConfig = SplitConfig()
    subject: SubjectConfig = SubjectConfig()
    markers: MarkersConfig = MarkersConfig()
    camera: CameraConfig = CameraConfig()
    occluders: OccludersConfig = OccludersConfig()
    observation: ObservationConfig = ObservationConfig()
    engine: EngineConfig = EngineConfig()
    methods: tuple[str, ...] = Field(default_factory=default_methods)
    sweep: dict[str, list[Any]] = Field(default_factory=dict)

    @field_validator("name")
    @classmethod
    def _one_component(cls, v):
        # The results go to --results/<name>: one path component, neither hidden nor '.' or '..', so that
        # nothing is written outside --results or into its cache.
        if not _NAME.match(v):
            raise ValueError(f"must be one path component of letters, digits, '_', '.' and '-', not starting with "
                             f"'.' or '-' (got {_short(v)})")
        if v in RESERVED_NAMES:
            raise ValueError(f"{v!r} is reserved (results/{v} is not a scenario's directory; reserved: "
                             f"{', '.join(RESERVED_NAMES)})")
        return v

    @field_validator("methods")
    @classmethod
    def _known_methods(cls, v):
        for i, m in enumerate(v):
            if m not in method_names():
                raise ValueError(f"[{i}]: unknown method {m!r} (valid: {', '.join(method_names())})")
        if len(set(v)) != len(v):
            raise ValueError(f"listed twice: {sorted({m for m in v if v.count(m) > 1})}")
        return v

    @model_validator(mode="after")
    def _check_split(self):
        procedural = self.database.source == "procedural"
        if procedural != (self.test.split in ("heldout", "captures")):
            valid = "heldout, captures" if procedural else "leave_one_out, cross_subject, all"
            raise ValueError(f"test.split: {self.test.split!r} does not fit database.source "
                             f"{self.database.source!r} (valid: {valid})")
        if not self.methods:
            raise ValueError("methods: empty list")
        if self.test.left is not None and not (procedural and self.test.split == "heldout"):
            raise ValueError(f"test.left: only procedural test performances choose a side (test.split 'heldout'), "
                             f"got test.split {self.test.split!r}")
        if self.database.with_captures and self.test.split != "captures":
            raise ValueError("database.with_captures: needs test.split 'captures' (a procedural database tested "
                             "on captures)")
        stream = self.test.stream
        if stream is not None:
            if procedural and self.test.split != "heldout":
                raise ValueError(f"test.split: streams of a procedural database are performed by held-out "
                                 f"subjects: 'heldout', got {self.test.split!r}")
            if procedural and stream.takes is not None:
                raise ValueError("test.stream.takes: capture takes need database.source 'capture'")
            if not procedural and self.test.split != "leave_one_out":
                raise ValueError(f"test.split: a capture stream is tested against a database trained without its "
                                 f"take: 'leave_one_out', got {self.test.split!r}")
            if not procedural and stream.takes is None:
                raise ValueError("test.stream.takes: a capture stream scenario lists its takes (file stems)")
        return self

    @property
    def classes(self) -> tuple[str, ...]:
        """The classes of a procedural database (capture databases are resolved by ``resolve_capture``)."""
        return self.database.classes or PROCEDURAL_CLASSES


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


def scene_spec(config: Scenario, rng: np.random.Generator) -> SceneSpec:
    """The scene of one run: per-run values (``random`` azimuth, seeds left to the run) drawn from ``rng`` in a
    fixed order (azimuth, marker seed, occluder seed, subject seed), each only when the scenario leaves it."""
    cam, mk, occ, subj = config.camera, config.markers, config.occluders, config.subject
    azimuth = float(rng.uniform(0.0, 360.0)) if cam.azimuth == RANDOM else float(cam.azimuth)
    marker_seed = mk.seed if mk.seed is not None else int(rng.integers(2**31))
    occ_seed = occ.seed if occ.seed is not None else int(rng.integers(2**31))
    subject_seed = 0
    if subj.limb_scale > 0:
        subject_seed = subj.seed if subj.seed is not None else int(rng.integers(2**31))
    # A preset at amount 0 is no obstacle (a sweep over the amount starts there).
    preset = occ.preset if occ.amount > 0 else "none"
    return SceneSpec(to_spec(mk, seed=marker_seed), to_spec(cam, azimuth=azimuth),
                     to_spec(occ, preset=preset, seed=occ_seed), to_spec(config.observation),
                     to_spec(subj, seed=subject_seed))


def tracker_config(config: Scenario) -> TrackerConfig:
    return TrackerConfig(**config.engine.model_dump())


# --- errors ------------------------------------------------------------------------------------------------

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
        msg += f" (got {_short(got)})"
    return msg


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


_UNION_TAG = re.compile(r"^(int|float|str|bool|none|literal\[.*\]|tuple\[.*\]|list\[.*\]|.*Section)$")


def _strip(loc: tuple) -> tuple:
    """Drop pydantic's union-member tags (``float``, ``literal['random']``) so the path is the user's key."""
    return tuple(p for p in loc if not (isinstance(p, str) and (_UNION_TAG.match(p) or p.startswith("function"))))


def _first_error(exc: ValidationError) -> tuple[str, str]:
    errors = exc.errors()
    loc = _strip(errors[0]["loc"])
    same = [e for e in errors if _strip(e["loc"]) == loc]
    path = _format_loc(loc)
    if len(same) > 1:   # a union: every alternative failed; say what each expected
        got = same[0].get("input")
        expected = " or ".join(dict.fromkeys(_message(e).split(" (got ")[0] for e in same))
        return path, f"{expected} (got {_short(got)})"
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
        path, msg = _first_error(exc)
        n_keys = len({_strip(e["loc"]) for e in exc.errors()})
        extra = f" (and {n_keys - 1} more)" if n_keys > 1 else ""
        raise ScenarioError(f"{where}: {path}: {msg}{extra}" if path else f"{where}: {msg}{extra}") from None


# --- the sweep grid ----------------------------------------------------------------------------------------

# Keys a sweep may not take: the capture set is resolved once per scenario (its directory, manifest and classes
# are checked at load), and the scenario seed is what every condition's draws derive from (conditions share
# their draws by design, and a swept value would collide with the run's `seed` column): repeats give
# independent draws.
UNSWEEPABLE = {"seed": "the scenario seed is shared by every condition (common random numbers); raise repeats for "
                       "independent draws",
               "database.capture_dir": "a capture set is resolved once per scenario",
               "database.manifest": "a capture set is resolved once per scenario"}


def _set_dotted(raw: dict, key: str, value: Any, where: str = "<scenario>") -> dict:
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


def _apply(raw: dict, values: Iterable[tuple[str, Any]], where: str) -> dict:
    out = {k: v for k, v in raw.items() if k != "sweep"}
    for k, v in values:
        out = _set_dotted(out, k, v, where)
    return out


def sweepable_keys() -> list[str]:
    keys = []
    for section, field in Scenario.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            keys += [f"{section}.{k}" for k in ann.model_fields]
        elif section not in ("name", "sweep"):
            keys.append(section)
    return [k for k in keys if k not in UNSWEEPABLE]


def _check_sweep_shape(sweep: dict, where: str) -> None:
    """Keys, list sizes, repeated values and the grid's size, before any value is validated (a grid of
    millions of conditions is refused at once, not after validating each)."""
    valid = sweepable_keys()
    for key, values in sweep.items():
        if key in UNSWEEPABLE:
            raise ScenarioError(f"{where}: sweep[{key!r}]: not sweepable: {UNSWEEPABLE[key]}")
        if key not in valid:
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
                                f"({_short(values)})") from None
        if len(set(texts)) != len(texts):
            raise ScenarioError(f"{where}: sweep[{key!r}]: a value is listed twice ({_short(values)})")


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
            out.append(Scenario.model_validate(_apply(raw, values, where)))
            continue
        except ValidationError as exc:
            path, msg = _first_error(exc)
        for k, i in zip(keys, combo):
            if _under(path, k):
                rest = path[len(k):].lstrip(".")
                raise ScenarioError(f"{where}: sweep[{k!r}][{i}]: {rest + ': ' if rest else ''}{msg}") from None
        everywhere = True
        for other in combos:
            try:
                Scenario.model_validate(_apply(raw, [(k, sweep[k][i]) for k, i in zip(keys, other)], where))
                everywhere = False
                break
            except ValidationError as again:
                if _first_error(again) != (path, msg):
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
    if cfg.database.source == "procedural" and cfg.test.split == "heldout":
        return len(cfg.classes) * cfg.test.demos_per_class
    return None


def _check_size(configs: list[Scenario], where: str) -> None:
    """Refuse a plan of more than MAX_RUNS runs before building it (a huge sweep or repeat count would hang)."""
    n = sum(cfg.repeats * (_runs_per_condition(cfg) or 1) for cfg in configs)
    if n > MAX_RUNS:
        raise ScenarioError(f"{where}: the plan has {n} runs ({len(configs)} conditions x repeats x test motions), "
                            f"more than {MAX_RUNS}: reduce repeats or the sweep")


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
        raise ScenarioError(f"{where}: sweep: must map dotted keys to lists of values, got {_short(sweep)}")
    for key, values in (sweep or {}).items():
        if not isinstance(key, str):
            raise ScenarioError(f"{where}: sweep: keys must be dotted names, got {_short(key)}")
        if not isinstance(values, list):
            raise ScenarioError(f"{where}: sweep[{key!r}]: must be a list of values, got {_short(values)}")
    sweep = sweep or {}
    if not sweep:
        scenario = _validate(raw, where)
    else:
        _check_sweep_shape(sweep, where)
        first = _apply(raw, [(k, v[0]) for k, v in sweep.items()], where)
        _check_conditions(raw, sweep, where)
        scenario = _validate(first | {"sweep": sweep}, where)
    conds = conditions(scenario)
    _check_size([c.config for c in conds], where)
    for cond in conds:
        _check_placement(cond, where)
        _check_limits(cond, where)
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; ``ScenarioError`` names the file and the key path. The file's
    size and kind are checked before it is read, and the YAML is read with ``harness.safe_yaml`` (aliases
    bounded, duplicate keys and oversized integers refused)."""
    raw = safe_yaml.load(path, ScenarioError, "scenario", MAX_SCENARIO_BYTES)
    return parse_scenario(raw if raw is not None else {}, str(path))


def conditions(scenario: Scenario) -> list[Condition]:
    """The Cartesian product of the sweep, in the order the keys and values are written (last key fastest)."""
    base = scenario.model_dump(mode="json")
    keys = list(scenario.sweep)
    out = []
    for i, combo in enumerate(itertools.product(*(scenario.sweep[k] for k in keys))):
        raw = _apply(base, zip(keys, combo), scenario.name)
        out.append(Condition(i, tuple(zip(keys, combo)), Scenario.model_validate(raw)))
    return out


def scenario_hash(scenario: Scenario) -> str:
    """A stable hash (hex, 16 digits) of the resolved scenario and the code version
    (``harness.version.code_version``); runs stored under another hash are stale."""
    text = json.dumps({"scenario": scenario.model_dump(mode="json"), "code": code_version()}, sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# --- capture sets ------------------------------------------------------------------------------------------

def resolve_mocap_dir(scenario: Scenario, override: str | Path | None = None, where: str | None = None) -> Path:
    """The capture directory: ``--mocap-dir`` beats ``database.capture_dir`` beats ``$HARNESS_MOCAP_DIR``;
    its manifest must be a regular file inside it once symbolic links are followed. ``where`` names the
    scenario file in errors (default: the scenario's name)."""
    from harness.motion.captures import CaptureSetError, inside

    where = where or scenario.name
    chosen = override or scenario.database.capture_dir or os.environ.get(MOCAP_ENV)
    if not chosen:
        raise ScenarioError(f"{where}: database.capture_dir: not set (give --mocap-dir DIR, "
                            f"database.capture_dir or ${MOCAP_ENV})")
    path = Path(chosen).expanduser().resolve()
    if not path.is_dir():
        raise ScenarioError(f"{where}: database.capture_dir: {path} is not a directory")
    try:
        inside(path, scenario.database.manifest, "database.manifest")
    except CaptureSetError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    return path


def resolve_capture(scenario: Scenario, mocap_dir: str | Path | None = None, where: str | None = None
                    ) -> Scenario:
    """Fix a capture scenario's directory and classes (default: the manifest's), checking listed classes,
    swept ones included, and that every manifest row's file is inside the directory (before any work).

    A procedural database tested on captures (``test.split: captures``) keeps its classes; every manifest
    class must be one of them. ``where`` names the scenario file in errors (default: its name)."""
    from harness.motion.captures import CaptureSetError, check_rows, read_manifest

    if scenario.database.source != "capture" and scenario.test.split != "captures":
        return scenario
    where = where or scenario.name
    root = resolve_mocap_dir(scenario, mocap_dir, where)
    try:
        rows = read_manifest(root / scenario.database.manifest)
        check_rows(root, rows)
    except CaptureSetError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    present = sorted({r.label for r in rows})
    if scenario.database.source == "procedural":
        for cond in conditions(scenario):
            label = "" if cond.label == "base" else f" (condition {cond.label})"
            for c in present:
                if c not in cond.config.classes:
                    raise ScenarioError(f"{where}: database.classes: the capture class {c!r} is not in the "
                                        f"database (classes: {', '.join(cond.config.classes)}){label}")
        db = scenario.database.model_copy(update={"capture_dir": str(root)})
        return scenario.model_copy(update={"database": db})
    for cond in conditions(scenario):
        label = "" if cond.label == "base" else f" (condition {cond.label})"
        for i, c in enumerate(cond.config.database.classes or ()):
            if c not in present:
                raise ScenarioError(f"{where}: database.classes[{i}]: unknown class {c!r} "
                                    f"(valid: {', '.join(present)}){label}")
        stream = cond.config.test.stream
        if stream is not None:
            takes = sorted({Path(r.file).stem for r in rows})
            for i, take in enumerate(stream.takes or ()):
                if take not in takes:
                    raise ScenarioError(f"{where}: test.stream.takes[{i}]: no manifest row of take {take!r} "
                                        f"(takes: {', '.join(takes)}){label}")
    classes = scenario.database.classes or tuple(present)
    db = scenario.database.model_copy(update={"capture_dir": str(root), "classes": tuple(classes)})
    return scenario.model_copy(update={"database": db})


# --- the schema as documentation -----------------------------------------------------------------------------

_PER_RUN_TEXT = {(MarkerSpec, "seed"): "none: drawn per run", (OccluderSpec, "seed"): "none: drawn per run",
                 (SubjectSpec, "seed"): "none: drawn per run", (CameraSpec, "azimuth"): "or `random`: drawn per run"}


def _default_text(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, tuple):
        return "[" + ", ".join(_default_text(v) for v in value) + "]"
    if isinstance(value, str):
        return f"`{value}`"
    return repr(value) if not isinstance(value, float) else f"{value:g}"


def _field_comments(cls: type) -> dict[str, str]:
    """The trailing ``# comment`` of each field line of a dataclass's source (the engine documents its settings
    that way)."""
    import inspect

    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    out = {}
    for line in source.splitlines():
        m = re.match(r"^\s+(\w+)\s*:[^#]*#\s*(.+)$", line)
        if m:
            out.setdefault(m.group(1), m.group(2).strip().replace("|", "/"))
    return out


@lru_cache(maxsize=1)
def schema_markdown() -> str:
    """The generated rows of the schema table for the sections that come from the spec types and the engine
    (``| key | default | unit | values | meaning |``); ``docs/evaluation.md`` holds them verbatim (tested)."""
    lines = ["| key | default | unit | values | meaning |", "|---|---|---|---|---|"]
    for section, spec_cls in (("subject", SubjectSpec), ("markers", MarkerSpec), ("camera", CameraSpec),
                              ("occluders", OccluderSpec), ("occluders.geoms[]", OccluderGeom),
                              ("observation", ObservationSpec)):
        for f in dataclasses.fields(spec_cls):
            meta = f.metadata
            values = meta.get("values", "")
            if (spec_cls, f.name) in _PER_RUN_TEXT:
                values += f"; {_PER_RUN_TEXT[(spec_cls, f.name)]}"
                default = _default_text(_PER_RUN[(spec_cls, f.name)][1])
            else:
                default = _default_text(_field_default(f))
            lines.append(f"| `{section}.{f.name}` | {default} | {meta.get('unit', '')} | {values} | "
                         f"{meta.get('meaning', '')} |")
    hints = typing.get_type_hints(TrackerConfig)
    comments = _field_comments(TrackerConfig)
    for f in dataclasses.fields(TrackerConfig):
        ann = hints[f.name]
        kind = ann.__name__ if isinstance(ann, type) else str(ann).replace("typing.", "")
        meaning = f.metadata.get("meaning") or comments.get(f.name) or "see docs/engine.md"
        lines.append(f"| `engine.{f.name}` | {_default_text(_field_default(f))} | | {kind} | {meaning} |")
    return "\n".join(lines) + "\n"
