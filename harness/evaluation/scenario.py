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

import dataclasses
import hashlib
import itertools
import json
import math
import os
import re
import typing
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model, field_validator, model_validator

from harness.engine import TrackerConfig
from harness.errors import EngineError, HarnessError
from harness.evaluation.methods import default_methods, method_names
from harness.motion.performer import CLASSES as PROCEDURAL_CLASSES
from harness.scene.spec import (CameraSpec, MarkerSpec, ObservationSpec, OccluderGeom, OccluderSpec, SceneError,
                                SceneSpec, SubjectSpec)
from harness.version import code_version

MOCAP_ENV = "HARNESS_MOCAP_DIR"
MAX_RUNS = 100_000          # a plan beyond this is refused at load (at seconds per run it would take weeks)
MAX_SCENARIO_BYTES = 1_000_000
RANDOM = "random"


class ScenarioError(HarnessError):
    """A scenario file that cannot be read or does not validate; the message names the file and key path."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class DatabaseConfig(_Section):
    """Where the motion database comes from and how it is trained."""

    source: Literal["procedural", "capture"] = "procedural"
    capture_dir: str | None = None          # capture only; else --mocap-dir or $HARNESS_MOCAP_DIR
    manifest: str = "MANIFEST.csv"          # capture only; relative to capture_dir
    classes: tuple[str, ...] | None = None  # default: all procedural classes / the manifest's classes
    train_demos: int = Field(8, ge=1, le=1000)   # demonstrations per class (procedural)
    states: int = Field(20, ge=2, le=500)   # HMM states per primitive
    seed: int = Field(0, ge=0)              # training seed (demo generation and HMM initialisation)
    fps: float = Field(30.0, gt=0, le=1000)  # frames per second of training and test motions
    with_captures: bool = False             # procedural, test.split captures: also train on the capture demos
                                            # of every subject but the test motion's

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
        if not 2 <= lo <= hi:
            raise ValueError(f"primitives: must be [min, max] with 2 <= min <= max, got {list(self.primitives)}")
        t_lo, t_hi = self.transition_s
        if not 0 < t_lo <= t_hi:
            raise ValueError(f"transition_s: must be [min, max] seconds with 0 < min <= max, got "
                             f"{list(self.transition_s)}")
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

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$", max_length=100)     # also the results directory name
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

def _set_dotted(raw: dict, key: str, value: Any) -> dict:
    out = json.loads(json.dumps(raw))
    node = out
    parts = key.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ScenarioError(f"sweep[{key!r}]: {p} is not a section")
    node[parts[-1]] = value
    return out


def sweepable_keys() -> list[str]:
    keys = []
    for section, field in Scenario.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            keys += [f"{section}.{k}" for k in ann.model_fields]
        elif section not in ("name", "sweep"):
            keys.append(section)
    return keys


def _check_sweep(raw: dict, scenario: Scenario, where: str) -> None:
    valid = sweepable_keys()
    for key, values in scenario.sweep.items():
        if key not in valid:
            raise ScenarioError(f"{where}: sweep[{key!r}]: unknown key (valid: {', '.join(valid)})")
        if len(values) == 0:
            raise ScenarioError(f"{where}: sweep[{key!r}]: empty list (give at least one value)")
        for i, v in enumerate(values):
            try:
                Scenario.model_validate(_set_dotted(raw, key, v) | {"sweep": {}})
            except ValidationError as exc:
                _, msg = _first_error(exc)
                raise ScenarioError(f"{where}: sweep[{key!r}][{i}]: {msg}") from None
        if len({json.dumps(v, sort_keys=True) for v in values}) != len(values):
            raise ScenarioError(f"{where}: sweep[{key!r}]: a value is listed twice ({_short(values)})")


def _check_size(raw: dict, scenario: Scenario, where: str) -> None:
    """Refuse a plan of more than MAX_RUNS runs before building it (a huge sweep or repeat count would hang)."""
    n_conditions = math.prod(len(v) for v in scenario.sweep.values())
    repeats = max([scenario.repeats] + list(scenario.sweep.get("repeats", [])))
    per_condition = 1
    if scenario.test.stream is not None:
        stream = scenario.test.stream
        per_condition = len(stream.takes) if stream.takes is not None else stream.count
    elif scenario.database.source == "procedural" and scenario.test.split == "heldout":
        demos = max([scenario.test.demos_per_class] + list(scenario.sweep.get("test.demos_per_class", [])))
        per_condition = len(scenario.classes) * demos
    n = n_conditions * repeats * per_condition
    if n > MAX_RUNS:
        raise ScenarioError(f"{where}: the plan has {n} runs ({n_conditions} conditions x {repeats} repeats x "
                            f"{per_condition} test motions), more than {MAX_RUNS}: reduce repeats or the sweep")


def _check_placement(cond: Condition, where: str) -> None:
    """Where the camera would stand, for every azimuth it can take (decidable cases only; see
    ``harness.scene.placement``)."""
    from harness.scene.placement import check_camera_placement

    cfg = cond.config
    cam = cfg.camera
    if cam.azimuth == RANDOM or (cam.motion == "orbit" and cam.orbit_rate != 0.0):
        azimuths = np.arange(0.0, 360.0, 1.0)
    else:
        azimuths = np.array([float(cam.azimuth)])
    try:
        check_camera_placement(to_spec(cam), to_spec(cfg.occluders), to_spec(cfg.subject), azimuths)
    except SceneError as exc:
        label = "" if cond.label == "base" else f" (condition {cond.label})"
        raise ScenarioError(f"{where}: {exc.key}: {exc.why}{label}") from None


def parse_scenario(raw: Any, where: str = "<scenario>") -> Scenario:
    """Validate a scenario given as a mapping (``where`` names its source in errors)."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where}: a scenario must be a mapping of keys to values, got {type(raw).__name__}")
    sweep = raw.get("sweep")
    if sweep is not None and not isinstance(sweep, dict):
        raise ScenarioError(f"{where}: sweep: must map dotted keys to lists of values, got {_short(sweep)}")
    for key, values in (sweep or {}).items():
        if not isinstance(values, list):
            raise ScenarioError(f"{where}: sweep[{key!r}]: must be a list of values, got {_short(values)}")
    scenario = _validate(raw, where)
    _check_sweep(raw, scenario, where)
    _check_size(raw, scenario, where)
    for cond in conditions(scenario):
        _check_placement(cond, where)
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; ``ScenarioError`` names the file and the key path."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except IsADirectoryError:
        raise ScenarioError(f"{path}: is a directory, not a scenario file") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read ({exc.strerror})") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise ScenarioError(f"{path}: {len(data)} bytes is too large for a scenario (at most {MAX_SCENARIO_BYTES})")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    if "\x00" in text:
        raise ScenarioError(f"{path}: not a text file (it contains NUL bytes)")
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        raise ScenarioError(f"{path}:{line} not valid YAML ({getattr(exc, 'problem', None) or type(exc).__name__})"
                            ) from None
    except RecursionError:
        raise ScenarioError(f"{path}: not valid YAML (nested too deeply)") from None
    return parse_scenario(raw if raw is not None else {}, str(path))


def conditions(scenario: Scenario) -> list[Condition]:
    """The Cartesian product of the sweep, in the order the keys and values are written (last key fastest)."""
    base = scenario.model_dump(mode="json")
    base["sweep"] = {}
    keys = list(scenario.sweep)
    out = []
    for i, combo in enumerate(itertools.product(*(scenario.sweep[k] for k in keys))):
        raw = base
        for k, v in zip(keys, combo):
            raw = _set_dotted(raw, k, v)
        out.append(Condition(i, tuple(zip(keys, combo)), Scenario.model_validate(raw)))
    return out


def scenario_hash(scenario: Scenario) -> str:
    """A stable hash (hex, 16 digits) of the resolved scenario and the code version
    (``harness.version.code_version``); runs stored under another hash are stale."""
    text = json.dumps({"scenario": scenario.model_dump(mode="json"), "code": code_version()}, sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# --- capture sets ------------------------------------------------------------------------------------------

def resolve_mocap_dir(scenario: Scenario, override: str | Path | None = None) -> Path:
    """The capture directory: ``--mocap-dir`` beats ``database.capture_dir`` beats ``$HARNESS_MOCAP_DIR``."""
    chosen = override or scenario.database.capture_dir or os.environ.get(MOCAP_ENV)
    if not chosen:
        raise ScenarioError(f"{scenario.name}: database.capture_dir: not set (give --mocap-dir DIR, "
                            f"database.capture_dir or ${MOCAP_ENV})")
    path = Path(chosen).expanduser().resolve()
    if not (path / scenario.database.manifest).is_file():
        raise ScenarioError(f"{scenario.name}: database.manifest: {path / scenario.database.manifest} not found")
    return path


def resolve_capture(scenario: Scenario, mocap_dir: str | Path | None = None) -> Scenario:
    """Fix a capture scenario's directory and classes (default: the manifest's), checking listed classes.

    A procedural database tested on captures (``test.split: captures``) keeps its classes; every manifest
    class must be one of them."""
    from harness.motion.captures import read_manifest

    if scenario.database.source != "capture" and scenario.test.split != "captures":
        return scenario
    root = resolve_mocap_dir(scenario, mocap_dir)
    rows = read_manifest(root / scenario.database.manifest)
    present = sorted({r.label for r in rows})
    if scenario.database.source == "procedural":
        for c in present:
            if c not in scenario.classes:
                raise ScenarioError(f"{scenario.name}: database.classes: the capture class {c!r} is not in the "
                                    f"database (classes: {', '.join(scenario.classes)})")
        db = scenario.database.model_copy(update={"capture_dir": str(root)})
        return scenario.model_copy(update={"database": db})
    classes = scenario.database.classes or tuple(present)
    for i, c in enumerate(classes):
        if c not in present:
            raise ScenarioError(f"{scenario.name}: database.classes[{i}]: unknown class {c!r} "
                                f"(valid: {', '.join(present)})")
    stream = scenario.test.stream
    if stream is not None:
        takes = sorted({Path(r.file).stem for r in rows})
        for i, take in enumerate(stream.takes or ()):
            if take not in takes:
                raise ScenarioError(f"{scenario.name}: test.stream.takes[{i}]: no manifest row of take {take!r} "
                                    f"(takes: {', '.join(takes)})")
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
