"""Which capture rows a scenario tests, and what each one holds out of its database: the one place of the split
rules, read by the runner (the plan) and the pipeline (each run's training set).

A capture test row's *group* under ``test.split`` is what its database never learns:

| split | group of a row | rows it holds out |
|---|---|---|
| ``subject`` | its set and subject | every row of that subject in that set |
| ``style`` | its set and style | every row of that style in that set (a row without a style is not tested: it only trains) |
| ``source`` | its set | the whole set (the database learns from the other sets, and procedural demonstrations when the source is ``both``) |
| ``row`` | the row itself | that row alone (leave one out) |
| ``none`` | nothing | nothing: the row is in its own training set (an optimistic bound) |

A row is tested when it is in ``test.capture_sets``, matches ``test.select``, and either its class is one of
the database's and still has training demonstrations once its group is held out (else it is *skipped*, listed in
the report), or its class is not one of the database's (``other``, or a class not listed): an *open-set* row
(``test.open_set``), scored apart and never in an accuracy.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from harness.evaluation.scenario import Scenario
from harness.motion.captures import CaptureRow, read_manifest

PROCEDURAL = "procedural"


def group(source: str, subject: str, style: str, demo: str, split: str) -> tuple | None:
    """A capture row's (or motion's) group under ``split`` (module docstring); None: not testable under it (a
    row without a style under ``style``), or holds nothing out (``none``)."""
    if split == "subject":
        return (source, subject)
    if split == "style":
        return (source, style) if style else None
    if split == "source":
        return (source,)
    if split == "row":
        return (source, demo)
    return None


@lru_cache(maxsize=8)
def _rows(dirs: tuple[str, ...], manifest: str) -> tuple[CaptureRow, ...]:
    return tuple(r for d in dirs for r in read_manifest(Path(d) / manifest, name=Path(d).name))


def capture_rows(cfg: Scenario) -> tuple[CaptureRow, ...]:
    """Every manifest row of the scenario's capture sets (resolved: ``scenario_captures.resolve_capture``), set
    by set in the order of ``database.capture_sets``."""
    return _rows(tuple(cfg.database.capture_dirs or ()), cfg.database.manifest)


def row_index(rows: tuple[CaptureRow, ...]) -> dict[tuple[str, str], list[int]]:
    """The positions in ``rows`` of each (set, class)'s rows, in manifest order: capture test motion ``d`` of
    class ``c`` in set ``s`` (a run's ``test_demo``) is ``rows[row_index(rows)[(s, c)][d]]``."""
    out: dict[tuple[str, str], list[int]] = {}
    for i, row in enumerate(rows):
        out.setdefault((row.set_name, row.label), []).append(i)
    return out


def _matches(values: dict, select) -> bool:
    return select is None or any(all(values[col] in allowed for col, allowed in f.items()) for f in select)


def selected(row: CaptureRow, select) -> bool:
    """Whether ``row`` matches some filter of ``test.select`` or ``database.select`` (None: every row)."""
    return _matches({"source": row.set_name, "subject": row.subject, "style": row.style, "class": row.label}, select)


def selected_motion(motion, select) -> bool:
    """``selected`` for a capture motion (its source, subject, style and class)."""
    return _matches({"source": motion.source, "subject": str(motion.subject), "style": motion.style,
                     "class": motion.label}, select)


@dataclass(frozen=True)
class Verdict:
    """What becomes of a capture row in a scenario: ``tested`` (a known class), ``open_set`` (a class the
    database does not have), or ``skipped`` with the reason."""

    row: CaptureRow
    demo: int
    kind: str
    why: str = ""


def verdicts(cfg: Scenario) -> list[Verdict]:
    """Every capture row of the scenario's test sets, with what becomes of it (module docstring)."""
    test, db = cfg.test, cfg.database
    rows = capture_rows(cfg)
    sets = test.capture_sets or db.capture_sets or ()
    classes = set(cfg.classes)
    out = []
    for (name, label), idx in row_index(rows).items():
        if name not in sets:
            continue
        for d, k in enumerate(idx):
            row = rows[k]
            if not selected(row, test.select):
                continue
            if label not in classes:
                out.append(Verdict(row, d, "open_set" if test.open_set else "skipped",
                                   "" if test.open_set else "a class the database does not have"))
                continue
            held = group(row.set_name, row.subject, row.style, row.demo, test.split)
            if test.split == "style" and held is None:
                out.append(Verdict(row, d, "skipped", "no style"))
            elif db.learns_procedural or any(
                    r.label == label and r.set_name in (db.capture_sets or ()) and selected(r, db.select) and (
                        held is None or group(r.set_name, r.subject, r.style, r.demo, test.split) != held)
                    for r in rows):
                out.append(Verdict(row, d, "tested"))
            else:
                out.append(Verdict(row, d, "skipped", f"no training row of {label} outside its {test.split}"))
    return out


def holds_out(test_motion, motion, split: str) -> bool:
    """Whether a database that ``test_motion`` (a capture test motion) is scored against must not learn the
    capture motion ``motion``: the same group under ``split``."""
    held = group(test_motion.source, str(test_motion.subject), test_motion.style, test_motion.demo, split)
    if held is None:
        return False
    return group(motion.source, str(motion.subject), motion.style, motion.demo, split) == held
