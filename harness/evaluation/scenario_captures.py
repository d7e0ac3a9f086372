"""A scenario's capture set: its directory (``--mocap-dir`` beats ``database.capture_dir`` beats
``$HARNESS_MOCAP_DIR``), its manifest, and the classes and takes a capture scenario may name, resolved and
checked before any work."""

from __future__ import annotations

import os
from pathlib import Path

from harness.evaluation.scenario import Scenario, ScenarioError
from harness.evaluation.sweep import conditions

MOCAP_ENV = "HARNESS_MOCAP_DIR"


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
