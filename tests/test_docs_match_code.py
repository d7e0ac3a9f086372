"""The reference docs name what the code has: every ``module.name`` and ``Class.member`` written in
``docs/architecture.md`` exists, and ``docs/settings.md`` lists every engine setting with its current default."""

import dataclasses
import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import harness
from harness.engine.config import TrackerConfig
from harness.evaluation.schema_docs import _default_text
from harness.settings import section_types

DOCS = Path(__file__).resolve().parents[1] / "docs"
# Instances the loop's picture names by their role, and the type each one is.
INSTANCES = {"track": "Track", "source": "PoseSource", "scorer": "Scorer"}
DOTTED = re.compile(r"(?<![\w/.])([A-Za-z_]\w*)\.([A-Za-z_]\w*)(?![\w/])")


def _modules() -> dict:
    """Every module of the package by its full name."""
    out = {"harness": harness}
    for info in pkgutil.walk_packages(harness.__path__, "harness."):
        if not info.name.endswith("__main__"):          # runs the command line
            out[info.name] = importlib.import_module(info.name)
    return out


def _resolve(head: str, modules: dict):
    """The object a doc's ``head`` names: a module by its last name, a class of the package, or a role."""
    head = INSTANCES.get(head, head)
    by_name = [m for name, m in modules.items() if name.rsplit(".", 1)[-1] == head]
    classes = {obj for m in modules.values() for name, obj in vars(m).items()
               if name == head and inspect.isclass(obj) and obj.__module__.startswith("harness")}
    found = by_name + list(classes)
    return found[0] if len(found) == 1 else None


def _has(obj, member: str) -> bool:
    """A module attribute, a class attribute or field, or an attribute the class's own methods assign."""
    if hasattr(obj, member):
        return True
    if inspect.isclass(obj):
        if dataclasses.is_dataclass(obj) and member in {f.name for f in dataclasses.fields(obj)}:
            return True
        return any(f"self.{member} =" in inspect.getsource(k) or f"self.{member}:" in inspect.getsource(k)
                   for k in obj.__mro__ if k.__module__.startswith("harness"))
    return False


def test_every_name_in_the_architecture_doc_exists():
    modules = _modules()
    text = (DOCS / "architecture.md").read_text()
    missing, checked = [], 0
    for head, member in set(DOTTED.findall(text)):
        if head == "harness":
            ok = f"harness.{member}" in modules
        elif member in ("py", "md", "yaml") or head in ("e", "i"):      # a file name, "e.g."
            continue
        else:
            obj = _resolve(head, modules)
            ok = obj is not None and _has(obj, member)
        checked += 1
        if not ok:
            missing.append(f"{head}.{member}")
    assert checked >= 20            # the doc names the loop's stages; the regex must find them
    assert not missing, f"docs/architecture.md names what the code does not have: {sorted(missing)}"


def test_the_resolver_refuses_a_name_the_code_does_not_have():
    modules = _modules()
    assert _has(_resolve("track", modules), "predict_belief")
    assert not _has(_resolve("track", modules), "recognise")
    assert _resolve("Tracker", modules) is not None and _has(_resolve("Tracker", modules), "particle_tracks")


def test_the_settings_reference_lists_every_setting_with_its_default():
    rows = {}
    for line in (DOCS / "settings.md").read_text().splitlines():
        m = re.match(r"^\| `([a-z_]+\.[a-z_]+)` \| ([^|]+) \|", line)
        if m:
            rows[m.group(1)] = m.group(2).strip()
    expected = {f"{section}.{f.name}": _default_text(f.default)
                for section, kind in section_types(TrackerConfig).items() for f in dataclasses.fields(kind)}
    assert set(rows) == set(expected), sorted(set(rows) ^ set(expected))
    wrong = {key: (rows[key], value) for key, value in expected.items() if rows[key] != value.strip("`")}
    assert not wrong, f"docs/settings.md states other defaults than the code (doc, code): {wrong}"
