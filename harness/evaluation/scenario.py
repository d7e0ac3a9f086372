"""Evaluation scenarios: the YAML schema.

A scenario fixes everything one evaluation needs (database, test split, subject, markers, camera, occluders,
observation noise, engine settings, methods, repeats, seed) plus ``sweep``: a mapping of dotted keys to lists
of values whose Cartesian product gives the *conditions* (``sweep``). Every section forbids unknown keys.

One schema: the ``markers``, ``camera``, ``occluders``, ``observation`` and ``subject`` sections are generated
from the scene's own spec types (``harness.scene.spec``: the same fields, defaults and checks; a seed or the
azimuth may be left to each run), and ``engine`` from the engine's settings sections
(``harness.engine.config``: ``engine.<section>.<field>``, each checked by building its section, the rules
between sections by building the ``TrackerConfig``; a former flat key is refused with its new place). Reading a
file, the checks of a whole plan and the error wording are ``loading``; the grid ``sweep``; capture sets
``scenario_captures``; the schema table in ``docs/evaluation.md`` ``schema_docs``. This module does not know
the method registry: ``loading`` checks the method names.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import typing
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, create_model, field_validator, model_validator

from harness.engine.config import TrackerConfig
from harness.errors import EngineError, HarnessError
from harness.motion.performer import CLASSES as PROCEDURAL_CLASSES
from harness.scene.spec import (CameraSpec, MarkerSpec, ObservationSpec, OccluderGeom, OccluderSpec, SceneError,
                                SceneSpec, SubjectSpec)
from harness.settings import section_types, unknown_key
from harness.version import code_version

MAX_RUNS = 100_000          # a plan beyond this is refused at load (at seconds per run it would take weeks)
MAX_STREAM_PRIMITIVES = 20      # primitives per procedural test stream
MAX_TRANSITION_S = 10.0
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
RESERVED_NAMES = ("cache", "baseline")   # --results/cache holds the database cache, results/baseline the
                                         # regression baseline: a scenario of that name would write into them
RANDOM = "random"


class ScenarioError(HarnessError):
    """A scenario file that cannot be read or does not validate; the message names the file and key path."""


def short(value: Any, limit: int = 60) -> str:
    """A value as an error message quotes it: its repr, cut at ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


SOURCES = ("procedural", "captures", "both")
SPLITS = ("subject", "style", "source", "row", "none")
CAPTURE_COLUMNS = ("source", "subject", "style", "class")
# Keys and values of before issue 59, refused with their new form (one line, the value's new spelling).
FORMER_VALUES = {
    ("database", "source", "capture"): "database.source: 'captures'",
    ("test", "split", "heldout"): "test.motions: procedural (held-out demonstrations are the default)",
    ("test", "split", "captures"): "test.motions: captures",
    ("test", "split", "leave_one_out"): "test.split: row",
    ("test", "split", "cross_subject"): "test.split: subject",
    ("test", "split", "all"): "test.split: none",
}
FORMER_KEYS = {
    ("database", "capture_dir"): "give --mocap-dir DIR (or database.capture_dirs: [DIR]) and database.capture_sets",
    ("database", "with_captures"): "database.source: both (the capture rows of the other subjects with "
                                   "test.split: subject)",
}


def _refuse_former(section: str):
    """A before-validator refusing a key or value of before issue 59 with its new form."""
    def check(cls, values):
        if isinstance(values, dict):
            for key, value in values.items():
                if (section, key) in FORMER_KEYS:
                    raise ValueError(f"{key}: no longer a key: {FORMER_KEYS[(section, key)]}")
                if isinstance(value, str) and (section, key, value) in FORMER_VALUES:
                    raise ValueError(f"{key}: {value!r} is now {FORMER_VALUES[(section, key, value)]}")
        return values
    return model_validator(mode="before")(check)


class DatabaseConfig(_Section):
    """What the motion database learns from and how it is trained."""

    _former = _refuse_former("database")
    source: Literal[SOURCES] = "procedural"     # procedural demonstrations, capture rows, or both
    capture_sets: tuple[str, ...] | None = None  # the capture sets of the scenario, by name (the directory's);
                                                 # default: every set given, else the repository's library
    capture_dirs: tuple[str, ...] | None = None  # where sets are (else --mocap-dir, $HARNESS_MOCAP_DIR, library)
    select: tuple[dict[Literal[CAPTURE_COLUMNS], tuple[str, ...]], ...] | None = None   # the capture rows it may
                                                                                      # learn (as test.select)
    manifest: str = "MANIFEST.csv"          # each set's manifest, a path inside its directory
    classes: tuple[str, ...] | None = None  # default: the procedural classes and the capture sets' classes
    train_demos: int = Field(8, ge=1, le=1000)   # demonstrations per class (procedural)
    states: int = Field(20, ge=2, le=500)   # HMM states per primitive (per side)
    mirrored: bool = True                   # both-handed: each HMM also holds its mirror-image chain
    background: bool = False                # also a class "unknown": an ergodic HMM of every class's frames
    by_source: bool = False                 # a chain per source of demonstrations (procedural, each capture set)
    seed: int = Field(0, ge=0)              # training seed (demo generation and HMM initialisation)
    fps: float = Field(30.0, gt=0, le=1000)  # frames per second of training and test motions

    @field_validator("manifest")
    @classmethod
    def _manifest_inside(cls, v):
        from harness.motion.captures import relative_path_problem

        problem = relative_path_problem(v)
        if problem:
            raise ValueError(f"{problem} (got {short(v)})")
        return v

    @model_validator(mode="after")
    def _check_classes(self):
        from harness.motion.captures import NO_PRIMITIVE

        if self.classes is not None:
            if len(self.classes) == 0:
                raise ValueError("classes: empty list (omit the key for the default classes)")
            if self.source == "procedural":
                for i, c in enumerate(self.classes):
                    if c not in PROCEDURAL_CLASSES:
                        raise ValueError(f"classes[{i}]: unknown class {c!r} (valid: {', '.join(PROCEDURAL_CLASSES)})")
            if NO_PRIMITIVE in self.classes:
                raise ValueError(f"classes: {NO_PRIMITIVE!r} marks capture rows of no primitive (open-set test "
                                 f"motions), never a database class")
            if len(set(self.classes)) != len(self.classes):
                raise ValueError(f"classes: listed twice: {sorted({c for c in self.classes if self.classes.count(c) > 1})}")
        for key in ("capture_sets", "capture_dirs"):
            value = getattr(self, key)
            if value is not None and (not value or len(set(value)) != len(value)):
                raise ValueError(f"{key}: give each at least once and none twice (got {list(value)})")
        return self

    @property
    def learns_procedural(self) -> bool:
        return self.source in ("procedural", "both")

    @property
    def learns_captures(self) -> bool:
        return self.source in ("captures", "both")


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
    """What is tested, and what a capture test motion holds out of its database.

    ``motions``: held-out procedural demonstrations (``demos_per_class`` per class, by subjects the database
    never saw), capture rows, or both. A capture row is tested against a database without every capture row of
    its ``split`` group (its subject, its style, its whole capture set, itself alone, or nothing); procedural
    demonstrations, when the database learns them, are never held out (their test subjects are never trained
    on). ``select``: the capture rows tested, a list of filters (a row is tested when some filter matches all its
    columns; none: every row of ``capture_sets``). Rows of a class the database does not have (``other``) are
    open-set test motions (``open_set``), scored apart. Or, with ``stream``, streams of several primitives
    (``docs/streams.md``)."""

    _former = _refuse_former("test")
    motions: Literal["procedural", "captures", "both"] = "procedural"
    demos_per_class: int = Field(2, ge=1, le=1000)  # procedural: held-out demos per class
    split: Literal[SPLITS] = "subject"
    capture_sets: tuple[str, ...] | None = None     # the sets whose rows are tested (default: every set)
    select: tuple[dict[Literal[CAPTURE_COLUMNS], tuple[str, ...]], ...] | None = None
    open_set: bool = True                           # test rows of classes the database does not have
    window_s: float | None = Field(None, gt=0, le=3600)   # a longer capture row is tested on its middle window
    capture_repeats: int | None = Field(None, ge=1, le=MAX_RUNS)  # repeats of capture rows (default: repeats)
    stream: StreamConfig | None = None
    # procedural: the share of test performances of every primitive that are left-sided (None: each primitive's
    # calibrated share); the database's demonstrations keep theirs
    left: float | None = Field(None, ge=0.0, le=1.0)

    @property
    def procedural(self) -> bool:
        return self.motions in ("procedural", "both")

    @property
    def captures(self) -> bool:
        return self.motions in ("captures", "both")


# --- sections generated from the scene's spec types and the engine's TrackerConfig ------------------------

# Fields a scenario may leave to each run: None (a seed drawn from the run's seed) or "random" (an azimuth
# drawn uniformly in [0, 360) per run). For validation the spec is built with a stand-in value.
PER_RUN: dict[tuple[type, str], tuple[Any, Any, Any]] = {
    (MarkerSpec, "seed"): (int | None, None, 0),
    (OccluderSpec, "seed"): (int | None, None, 0),
    (SubjectSpec, "seed"): (int | None, None, 0),
    (CameraSpec, "azimuth"): (float | Literal["random"], 0.0, 0.0),
}
_SECTION_OF: dict[type, type[BaseModel]] = {}


def field_default(f: dataclasses.Field) -> Any:
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
    the spec's own checks (bounds, finite numbers, names) are the scenario's. A spec's error carries the field
    (``key``), what was wrong (``why``) and the value: scene specs raise ``SceneError``, the engine's settings
    sections ``EngineError``."""
    hints = typing.get_type_hints(spec_cls)
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(spec_cls):
        if (spec_cls, f.name) in PER_RUN:
            ann, default, _ = PER_RUN[(spec_cls, f.name)]
            fields[f.name] = (ann, default)
            continue
        ann = hints[f.name]
        if typing.get_origin(ann) is tuple and typing.get_args(ann)[0] in _SECTION_OF:   # nested spec types
            ann = tuple[_SECTION_OF[typing.get_args(ann)[0]], ...]
        fields[f.name] = (ann, field_default(f))

    def check(self):
        try:
            to_spec(self, spec_cls)
        except (SceneError, EngineError) as exc:
            raise ValueError(f"{_spec_key(exc)}: {exc.why} (got {exc.value!r})") from None
        return self

    model = create_model(name, __base__=_Section, __doc__=spec_cls.__doc__, __module__=__name__,
                         __validators__={"_spec_checks": model_validator(mode="after")(check)}, **fields)
    model.spec_type = spec_cls
    _SECTION_OF[spec_cls] = model
    globals()[name] = model         # so that pickle (the runner's workers) finds it by its qualified name
    return model


def to_spec(section: BaseModel, spec_cls: type | None = None, **values: Any):
    """The spec a generated section describes; ``values`` fill the per-run fields (seeds, azimuth), which
    otherwise take their stand-ins."""
    spec_cls = spec_cls or section.spec_type
    kwargs = {}
    for f in dataclasses.fields(spec_cls):
        v = values.get(f.name, getattr(section, f.name))
        if (spec_cls, f.name) in PER_RUN and (v is None or v == RANDOM):
            v = PER_RUN[(spec_cls, f.name)][2]
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


def tracker_config(config) -> TrackerConfig:
    """The engine settings of a scenario (or of its ``engine`` section)."""
    engine = getattr(config, "engine", config)
    return TrackerConfig(**{name: to_spec(getattr(engine, name)) for name in section_types(TrackerConfig)})


def _engine_section() -> type[BaseModel]:
    """``engine``: one generated section per settings section of ``TrackerConfig``; a key that is not a section
    (a former flat setting) is refused with its new place, and the rules between sections are checked by
    building the ``TrackerConfig``."""
    kinds = section_types(TrackerConfig)
    sections = {name: _section_from_spec(kind, f"Engine{kind.__name__}") for name, kind in kinds.items()}

    def refuse_flat(cls, values):
        if isinstance(values, dict):
            for key in values:
                if key not in sections:
                    moved = unknown_key(TrackerConfig, key, "setting").removeprefix(f"setting {key} ")
                    raise ValueError(f"{key}: {moved.replace('moved to ', 'moved to engine.')}"
                                     if moved.startswith("moved") else f"{key}: unknown section (sections: "
                                     f"{', '.join(sections)})")
        return values

    def check(self):
        try:
            tracker_config(self)
        except EngineError as exc:
            raise ValueError(str(exc).removeprefix("engine setting ").removeprefix("engine settings ")) from None
        return self

    return create_model("EngineConfig", __base__=_Section, __doc__=TrackerConfig.__doc__, __module__=__name__,
                        __validators__={"_flat_keys": model_validator(mode="before")(refuse_flat),
                                        "_tracker_checks": model_validator(mode="after")(check)},
                        **{name: (model, model()) for name, model in sections.items()})


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
    methods: tuple[str, ...] | None = None      # None: the registry's default (``loading`` fills it in)
    # The code version of each method from outside the package (``module:function`` or installed), stamped by
    # ``loading`` from the methods' code and never written in a file: part of the scenario hash, so that rows
    # of changed method code are never mixed with old ones.
    method_versions: dict[str, str] = Field(default_factory=dict)
    sweep: dict[str, list[Any]] = Field(default_factory=dict)

    @field_validator("name")
    @classmethod
    def _one_component(cls, v):
        # The results go to --results/<name>: one path component, neither hidden nor '.' or '..', so that
        # nothing is written outside --results or into its cache.
        if not _NAME.match(v):
            raise ValueError(f"must be one path component of letters, digits, '_', '.' and '-', not starting with "
                             f"'.' or '-' (got {short(v)})")
        if v in RESERVED_NAMES:
            raise ValueError(f"{v!r} is reserved (results/{v} is not a scenario's directory; reserved: "
                             f"{', '.join(RESERVED_NAMES)})")
        return v

    @field_validator("methods")
    @classmethod
    def _methods_listed_once(cls, v):
        if v is not None and len(set(v)) != len(v):
            raise ValueError(f"listed twice: {sorted({m for m in v if v.count(m) > 1})}")
        return v

    @model_validator(mode="after")
    def _check_split(self):
        db, test = self.database, self.test
        if self.methods is not None and not self.methods:
            raise ValueError("methods: empty list")
        if test.procedural and not db.learns_procedural:
            raise ValueError(f"test.motions: {test.motions!r} tests procedural demonstrations, which a database of "
                             f"database.source {db.source!r} never learns (source: procedural or both)")
        if test.left is not None and not test.procedural:
            raise ValueError(f"test.left: only procedural test performances choose a side, got test.motions "
                             f"{test.motions!r}")
        for key in ("capture_sets", "select", "window_s", "capture_repeats"):
            if getattr(test, key) is not None and not test.captures:
                raise ValueError(f"test.{key}: set for capture test rows, but test.motions is {test.motions!r}")
        if test.capture_sets is not None and db.capture_sets is not None:
            for i, name in enumerate(test.capture_sets):
                if name not in db.capture_sets:
                    raise ValueError(f"test.capture_sets[{i}]: {name!r} is not one of database.capture_sets "
                                     f"({', '.join(db.capture_sets)})")
        stream = test.stream
        if stream is not None:
            if stream.takes is None and test.motions != "procedural":
                raise ValueError("test.stream: procedural streams are performed by held-out subjects: test.motions "
                                 "procedural")
            if stream.takes is not None and (test.motions != "captures" or not db.learns_captures
                                             or test.split != "row"):
                raise ValueError("test.stream.takes: a capture take is tested against a database of the capture "
                                 "rows without its own: database.source captures or both, test.motions captures, "
                                 "test.split row")
        return self

    @property
    def classes(self) -> tuple[str, ...]:
        """The database's classes: as listed, else the procedural ones (a scenario with capture sets has them
        fixed by ``scenario_captures.resolve_capture``)."""
        return self.database.classes or PROCEDURAL_CLASSES

    @property
    def uses_captures(self) -> bool:
        """Whether the scenario reads capture sets (to learn from or to test)."""
        return self.database.learns_captures or self.test.captures


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


def scenario_hash(scenario: Scenario) -> str:
    """A stable hash (hex, 16 digits) of the resolved scenario and the code version
    (``harness.version.code_version``); runs stored under another hash are stale."""
    text = json.dumps({"scenario": scenario.model_dump(mode="json"), "code": code_version()}, sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]
