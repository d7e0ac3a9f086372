"""Evaluation scenarios: the YAML schema, its validation, and the sweep grid.

A scenario fixes everything one evaluation needs (database, test split, markers, camera, occluders,
observation noise, engine settings, methods, repeats, seed) plus ``sweep``: a mapping of dotted keys to lists of
values whose Cartesian product gives the *conditions*. Every section forbids unknown keys, and every error
names the key path and what was expected, for example::

    default.yaml: camera.distnce: unknown key
    default.yaml: sweep['markers.count']: empty list (give at least one value)
    default.yaml: database.classes[3]: unknown class 'wlak' (valid: bow, jump, ...)

The schema with every default and unit is documented in ``docs/evaluation.md``.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from harness.errors import HarnessError

# The procedural performer's primitives (harness.motion.performer.CLASSES); repeated here so that a scenario
# can be checked without importing the simulator side. tests/test_scenario.py checks the two agree when the
# performer is present.
PROCEDURAL_CLASSES: tuple[str, ...] = ("walk", "run", "jump", "squat", "kick", "punch", "wave", "bow", "throw",
                                       "jumping_jack")
METHODS: tuple[str, ...] = ("full", "gt_base", "no_database", "joint_space")
MOCAP_ENV = "HARNESS_MOCAP_DIR"


class ScenarioError(HarnessError):
    """A scenario file that cannot be read or does not validate; the message names the file and key path."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DatabaseConfig(_Section):
    """Where the motion database comes from and how it is trained."""

    source: Literal["procedural", "capture"] = "procedural"
    capture_dir: str | None = None          # capture only; else --mocap-dir or $HARNESS_MOCAP_DIR
    manifest: str = "MANIFEST.csv"          # capture only; relative to capture_dir
    classes: tuple[str, ...] | None = None  # default: all procedural classes / the manifest's classes
    train_demos: int = Field(8, ge=1)       # demonstrations per class (procedural)
    states: int = Field(20, ge=2)           # HMM states per primitive
    seed: int = Field(0, ge=0)              # training seed (demo generation and HMM initialisation)
    fps: float = Field(30.0, gt=0)          # frames per second of training and test motions
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


class SplitConfig(_Section):
    """Which motions are tested: held-out procedural demos, a split of the capture set, or (``captures``) every
    capture demonstration against a procedural database (sim-to-real)."""

    demos_per_class: int = Field(2, ge=1)  # procedural: held-out demos per class
    split: Literal["heldout", "captures", "leave_one_out", "cross_subject", "all"] = "heldout"


class MarkersConfig(_Section):
    count: int = Field(100, ge=1)          # random surface sites on the body
    seed: int | None = None                # None: drawn from the run's seed (new placement every run)


class CameraConfig(_Section):
    distance: float = Field(4.0, gt=0)                  # metres from the subject's start position
    azimuth: float | Literal["random"] = 0.0            # degrees about world z; 0 looks at the subject's front
    elevation: float = Field(10.0, ge=-89.0, le=89.0)   # degrees above the horizon
    fovy: float = Field(45.0, gt=0, lt=180)             # vertical field of view, degrees
    width: int = Field(640, ge=16)                      # pixels
    height: int = Field(480, ge=16)                     # pixels
    look_at_height: float = 0.9                         # metres above the floor
    motion: Literal["static", "orbit"] = "static"
    orbit_rate: float = 0.0                             # degrees per second (motion: orbit)


class OccludersConfig(_Section):
    preset: str = Field("none", min_length=1)           # a preset name of harness.scene (checked there)
    amount: float = Field(0.0, ge=0.0, le=1.0)          # fraction of the subject the preset aims to hide
    seed: int | None = None                             # None: drawn from the run's seed


class ObservationConfig(_Section):
    mode: Literal["geometric", "rendered"] = "geometric"
    noise_px: float = Field(1.0, ge=0.0)                # std of pixel noise on positions, pixels
    dropout: float = Field(0.0, ge=0.0, lt=1.0)         # probability a visible flow is dropped
    outliers: float = Field(0.0, ge=0.0, lt=1.0)        # fraction of flows replaced by random outliers


class EngineConfig(_Section):
    particles: int = Field(200, ge=1)
    model_points: int = Field(150, ge=1)
    model_seed: int = Field(7, ge=0)                    # the engine's own surface sample (not the markers')
    init_distance: tuple[float, float] = (2.0, 8.0)     # metres, prior range of the subject's distance

    @field_validator("init_distance")
    @classmethod
    def _ordered(cls, v):
        if not 0 < v[0] < v[1]:
            raise ValueError(f"must be [near, far] with 0 < near < far metres, got {list(v)}")
        return v


class Scenario(_Section):
    """A validated scenario; ``sweep`` maps dotted keys to the values each condition takes."""

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")     # also the results directory name
    seed: int = Field(0, ge=0)
    repeats: int = Field(1, ge=1)
    database: DatabaseConfig = DatabaseConfig()
    test: SplitConfig = SplitConfig()
    markers: MarkersConfig = MarkersConfig()
    camera: CameraConfig = CameraConfig()
    occluders: OccludersConfig = OccludersConfig()
    observation: ObservationConfig = ObservationConfig()
    engine: EngineConfig = EngineConfig()
    methods: tuple[Literal["full", "gt_base", "no_database", "joint_space"], ...] = METHODS
    sweep: dict[str, list[Any]] = Field(default_factory=dict)

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


def _format_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("function-after", "function-before") or str(part).startswith("function-"):
            continue
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
        msg += f" (got {got!r})"
    return msg


_UNION_TAG = re.compile(r"^(int|float|str|bool|none|literal\[.*\]|tuple\[.*\]|list\[.*\])$")


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
        return path, f"{expected} (got {got!r})"
    msg = _message(errors[0])
    # model_validator messages already start with their own key path ("classes[3]: ...").
    if errors[0]["type"] == "value_error" and ":" in msg:
        head = msg.split(":", 1)[0]
        if " " not in head:
            return (f"{path}.{head}" if path else head), msg.split(":", 1)[1].strip()
    return path, msg


def _validate(raw: dict, where: str) -> Scenario:
    try:
        return Scenario.model_validate(raw)
    except ValidationError as exc:
        path, msg = _first_error(exc)
        n_keys = len({_strip(e["loc"]) for e in exc.errors()})
        extra = f" (and {n_keys - 1} more)" if n_keys > 1 else ""
        raise ScenarioError(f"{where}: {path}: {msg}{extra}" if path else f"{where}: {msg}{extra}") from None


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


def _sweepable_keys() -> list[str]:
    keys = []
    for section, field in Scenario.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            keys += [f"{section}.{k}" for k in ann.model_fields]
        elif section not in ("name", "sweep"):
            keys.append(section)
    return keys


def _check_sweep(raw: dict, scenario: Scenario, where: str) -> None:
    valid = _sweepable_keys()
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
            raise ScenarioError(f"{where}: sweep[{key!r}]: a value is listed twice ({values})")


def parse_scenario(raw: Any, where: str = "<scenario>") -> Scenario:
    """Validate a scenario given as a mapping (``where`` names its source in errors)."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where}: a scenario must be a mapping of keys to values, got {type(raw).__name__}")
    sweep = raw.get("sweep")
    if sweep is not None and not isinstance(sweep, dict):
        raise ScenarioError(f"{where}: sweep: must map dotted keys to lists of values, got {sweep!r}")
    for key, values in (sweep or {}).items():
        if not isinstance(values, list):
            raise ScenarioError(f"{where}: sweep[{key!r}]: must be a list of values, got {values!r}")
    scenario = _validate(raw, where)
    _check_sweep(raw, scenario, where)
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; ``ScenarioError`` names the file and the key path."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        raise ScenarioError(f"{path}:{line} not valid YAML ({getattr(exc, 'problem', exc)})") from None
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
    """A stable hash (hex, 16 digits) of the resolved scenario; runs stored under another hash are stale."""
    text = json.dumps(scenario.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


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


def read_manifest(path: Path) -> list[dict[str, str]]:
    """Rows of a capture manifest CSV (``file, format, class, subject, ...``), in file order."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    for i, row in enumerate(rows):
        for key in ("file", "class", "subject"):
            if not row.get(key):
                raise ScenarioError(f"{path}: line {i + 2}: column {key!r} is empty or missing")
    return rows


def resolve_capture(scenario: Scenario, mocap_dir: str | Path | None = None) -> Scenario:
    """Fix a capture scenario's directory and classes (default: the manifest's), checking listed classes.

    A procedural database tested on captures (``test.split: captures``) keeps its classes; every manifest
    class must be one of them."""
    if scenario.database.source != "capture" and scenario.test.split != "captures":
        return scenario
    root = resolve_mocap_dir(scenario, mocap_dir)
    rows = read_manifest(root / scenario.database.manifest)
    present = sorted({r["class"] for r in rows})
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
    db = scenario.database.model_copy(update={"capture_dir": str(root), "classes": tuple(classes)})
    return scenario.model_copy(update={"database": db})
