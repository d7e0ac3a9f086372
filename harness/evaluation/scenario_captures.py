"""A scenario's capture sets: which directories its set names stand for, their manifests, and the classes and
takes a scenario may name, resolved and checked before any work.

A set is a directory with a manifest (``harness.motion.captures``), named by the directory's name. Where a named
set is found, first match wins: ``--mocap-dir DIR`` (repeatable), the scenario's ``database.capture_dirs``,
``$HARNESS_MOCAP_DIR`` (directories separated by ``os.pathsep``), then the repository's capture library
(``captures/<name>``: humanoid56 trajectories retargeted from the shared captures, ``docs/captures.md``). A scenario
that names no sets uses every set given on the command line, in the scenario or in the environment, or else the
whole library.
"""

from __future__ import annotations

import os
from pathlib import Path

from harness.evaluation.scenario import PROCEDURAL_CLASSES, Scenario, ScenarioError
from harness.evaluation.sweep import conditions

MOCAP_ENV = "HARNESS_MOCAP_DIR"
LIBRARY = Path(__file__).resolve().parents[2] / "captures"


def library_sets(library: Path | None = None) -> dict[str, Path]:
    """The capture library's sets by name (each a directory of ``library``, default ``LIBRARY``, with a
    manifest)."""
    library = LIBRARY if library is None else library
    if not library.is_dir():
        return {}
    return {d.name: d for d in sorted(library.iterdir()) if (d / "MANIFEST.csv").is_file()}


def _given_dirs(scenario: Scenario, override) -> list[tuple[str, str]]:
    """``(where, directory)`` of every set given by hand, most binding first."""
    cli = [override] if isinstance(override, (str, Path)) else list(override or [])
    env = [d for d in os.environ.get(MOCAP_ENV, "").split(os.pathsep) if d]
    return ([("--mocap-dir", str(d)) for d in cli] + [("database.capture_dirs", d)
                                                       for d in scenario.database.capture_dirs or ()]
            + [(f"${MOCAP_ENV}", d) for d in env])


def available_sets(scenario: Scenario, override=None, where: str | None = None) -> tuple[dict[str, Path], list[str]]:
    """Every set the scenario can name, by name (first match wins; module docstring), and the names of those
    given by hand, in order. A given directory that does not exist is an error."""
    where = where or scenario.name
    found: dict[str, Path] = {}
    for origin, directory in _given_dirs(scenario, override):
        path = Path(directory).expanduser().resolve()
        if not path.is_dir():
            raise ScenarioError(f"{where}: {origin} {directory}: not a directory")
        found.setdefault(path.name, path)
    given = list(found)
    for name, path in library_sets().items():
        found.setdefault(name, path)
    return found, given


def resolve_mocap_dirs(scenario: Scenario, override=None, where: str | None = None) -> list[Path]:
    """The directories of the scenario's capture sets, in the order of ``database.capture_sets`` (default: the
    sets given by hand, else the library's); each set's manifest must be a regular file inside it."""
    from harness.motion.captures import CaptureSetError, inside

    where = where or scenario.name
    found, given = available_sets(scenario, override, where)
    names = scenario.database.capture_sets or tuple(given or found)
    if not names:
        raise ScenarioError(f"{where}: database.capture_sets: no capture set (give --mocap-dir DIR, "
                            f"database.capture_dirs or ${MOCAP_ENV}; the library {LIBRARY} has none)")
    out = []
    for i, name in enumerate(names):
        if name not in found:
            raise ScenarioError(f"{where}: database.capture_sets[{i}]: no capture set {name!r} (sets found: "
                                f"{', '.join(found) or 'none'}; give its directory with --mocap-dir)")
        try:
            inside(found[name], scenario.database.manifest, f"{name}: database.manifest")
        except CaptureSetError as exc:
            raise ScenarioError(f"{where}: {exc}") from None
        out.append(found[name])
    return out


def resolve_capture(scenario: Scenario, mocap_dir=None, where: str | None = None) -> Scenario:
    """Fix a scenario's capture sets (their names and directories) and its classes, checking every manifest and
    every row's files (inside their directory) before any work.

    Classes, unless listed: the procedural ones when the database learns procedural demonstrations, then the
    capture sets' own (never ``other``: rows of no primitive are open-set test motions). A listed class must
    have demonstrations somewhere; a listed capture take must exist. ``mocap_dir``: a directory or a list
    (``--mocap-dir``, repeatable). ``where`` names the scenario file in errors (default: its name)."""
    from harness.motion.captures import NO_PRIMITIVE, CaptureSetError, check_rows, read_manifest

    if not any(cond.config.uses_captures for cond in conditions(scenario)):
        return scenario
    where = where or scenario.name
    dirs = resolve_mocap_dirs(scenario, mocap_dir, where)
    rows = []
    for root in dirs:
        try:
            found = read_manifest(root / scenario.database.manifest, name=root.name)
            check_rows(root, found)
        except CaptureSetError as exc:
            raise ScenarioError(f"{where}: {exc}") from None
        rows += found
    db, test = scenario.database, scenario.test
    names = tuple(d.name for d in dirs)
    for i, name in enumerate(test.capture_sets or ()):
        if name not in names:
            raise ScenarioError(f"{where}: test.capture_sets[{i}]: {name!r} is not one of the scenario's capture "
                                f"sets ({', '.join(names)})")
    captured = sorted({r.label for r in rows} - {NO_PRIMITIVE})
    procedural = PROCEDURAL_CLASSES if db.learns_procedural else ()
    classes = db.classes or tuple(procedural) + tuple(c for c in captured if c not in procedural)
    for cond in conditions(scenario):
        label = "" if cond.label == "base" else f" (condition {cond.label})"
        present = set(procedural if cond.config.database.learns_procedural else ()) | set(captured)
        for i, c in enumerate(cond.config.database.classes or ()):
            if c not in present:
                raise ScenarioError(f"{where}: database.classes[{i}]: unknown class {c!r} (valid: "
                                    f"{', '.join(sorted(present))}){label}")
        stream = cond.config.test.stream
        if stream is not None and stream.takes is not None:
            if len(dirs) != 1:
                raise ScenarioError(f"{where}: test.stream.takes: capture takes come from one capture set, the "
                                    f"scenario has {len(dirs)}")
            if any(r.format == "npz" for r in rows):
                raise ScenarioError(f"{where}: test.stream.takes: a take is retargeted whole from its capture "
                                    f"files, which the set {dirs[0].name!r} ({dirs[0]}) does not hold (the library "
                                    f"keeps the rows only): give the source set with --mocap-dir")
            takes = sorted({Path(r.file).stem for r in rows})
            for i, take in enumerate(stream.takes):
                if take not in takes:
                    raise ScenarioError(f"{where}: test.stream.takes[{i}]: no manifest row of take {take!r} "
                                        f"(takes: {', '.join(takes)}){label}")
    resolved = db.model_copy(update={"capture_sets": names, "capture_dirs": tuple(str(d) for d in dirs),
                                     "classes": tuple(classes)})
    return scenario.model_copy(update={"database": resolved})
