"""Methods from outside the package: a scenario's ``methods`` entry ``module.path:function``, or the name of a method
an installed package registers under the entry-point group ``ENTRY_POINT_GROUP``.

Either is a function of the built-in methods' protocol (``harness.evaluation.methods``, ``docs/methods.md``),
declared with ``methods.declare``. ``resolve`` imports it once per process and keeps it in ``methods.EXTERNAL``
under the name as written (the ``method`` column of ``runs.csv``). Its *version* is the version of the code it
comes from (``source_version``: the installed distribution's version, if any, and a hash of the files of the
module's top-level package), so that rows of changed code are never mixed with old ones: ``loading`` stamps the
versions on the scenario (``Scenario.method_versions``, part of the scenario hash), and a worker whose method has
another version refuses the run.

A package registers a method in its ``pyproject.toml``::

    [project.entry-points."harness.methods"]
    flow_knn = "flowclf.method:estimate"
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import os
import re
import sys
from functools import lru_cache
from pathlib import Path

from harness.evaluation.methods import (BASE_POSE_COLUMNS, DECLARATION, EXTERNAL, METHODS, PROTOCOL_VERSION,
                                        RECOVERY_COLUMNS, Method, MethodError, first_line)

ENTRY_POINT_GROUP = "harness.methods"
_TARGET = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*$")     # module.path:function
ENTRY_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
MAX_HASHED_BYTES = 256 * 2**20     # a package's files hashed for its version (a data file beyond is sized only)


def is_target(name: str) -> bool:
    """Whether ``name`` is written ``module.path:function``."""
    return ":" in name


def entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    """The installed methods: entry-point name -> entry point (group ``ENTRY_POINT_GROUP``)."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def resolve(name: str) -> Method:
    """The method a scenario names: built-in, ``module:function`` or an installed entry point (in that order; an
    entry point cannot shadow a built-in name). ``MethodError`` naming the method when it cannot be imported, is
    not callable, is not declared, or declares another protocol version."""
    if name in METHODS:
        return METHODS[name]
    if name in EXTERNAL:
        return EXTERNAL[name]
    if is_target(name):
        if not _TARGET.match(name):
            raise MethodError(f"method {name!r}: write an outside method as module.path:function")
        module_name, function = name.split(":")
        fn = _load(name, module_name, function)
    else:
        installed = entry_points()
        if name not in installed:
            raise MethodError(f"unknown method {name!r} (built in: {', '.join(METHODS)}; installed: "
                              f"{', '.join(sorted(installed)) or 'none'}; or module.path:function)")
        ep = installed[name]
        if not ENTRY_NAME.match(name):
            raise MethodError(f"method {name!r}: an installed method's name must be letters, digits, '_', '.', '-'")
        if not _TARGET.match(ep.value):
            raise MethodError(f"method {name!r}: its entry point {ep.value!r} is not module.path:function")
        module_name, function = ep.value.split(":")
        fn = _load(name, module_name, function)
    EXTERNAL[name] = _method(name, fn, source_version(module_name))
    return EXTERNAL[name]


def _load(name: str, module_name: str, function: str):
    """``module_name.function``, imported. Like ``python -m`` (and unlike the installed ``harness`` script), the
    working directory is searched for the module too, so that a method in a file beside the scenario runs."""
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.append(cwd)
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:           # ImportError, a SyntaxError, whatever the module's own code raised
        raise MethodError(f"method {name!r}: cannot import module {module_name!r} ({first_line(exc)})") from None
    if not hasattr(module, function):
        raise MethodError(f"method {name!r}: module {module_name!r} has no {function!r}")
    fn = getattr(module, function)
    if not callable(fn):
        raise MethodError(f"method {name!r}: {module_name}.{function} is not callable (got {type(fn).__name__})")
    return fn


def _method(name: str, fn, version: str) -> Method:
    """A ``Method`` from a function's declaration (``methods.declare``), checked."""
    declared = getattr(fn, DECLARATION, None)
    if not isinstance(declared, dict):
        raise MethodError(f"method {name!r}: not declared; decorate the function with "
                          f"@harness.evaluation.methods.declare(recognises=..., recovers=...)")
    unknown = sorted(set(declared) - {"protocol", "recognises", "recovers", "given"})
    if unknown:
        raise MethodError(f"method {name!r}: unknown declaration key {unknown[0]!r}")
    protocol = declared.get("protocol", PROTOCOL_VERSION)
    if protocol != PROTOCOL_VERSION:
        raise MethodError(f"method {name!r}: declares protocol {protocol!r}; this harness runs protocol "
                          f"{PROTOCOL_VERSION}")
    recognises, recovers = declared.get("recognises"), declared.get("recovers")
    if not isinstance(recognises, bool) or not isinstance(recovers, bool):
        raise MethodError(f"method {name!r}: declare recognises and recovers as true or false")
    if not (recognises or recovers):
        raise MethodError(f"method {name!r}: declares neither recognises nor recovers (nothing to score)")
    given = tuple(declared.get("given", ()))
    bad = [c for c in given if c not in RECOVERY_COLUMNS]
    if bad or (given and not recovers):
        raise MethodError(f"method {name!r}: given columns must be recovery columns of a recovering method "
                          f"(e.g. {', '.join(BASE_POSE_COLUMNS[:2])}), got {bad or list(given)}")
    return Method(name, fn, recognises, recovers, given, default=False, version=version)


def source_version(module_name: str) -> str:
    """``<distribution version>+<12 hex digits>`` of the code a method comes from: the version of the installed
    distribution that holds the module's top-level package (``0`` when none does: a file in the working
    directory) and a SHA-256 over the paths and contents of that package's files (``__pycache__`` left out), or
    of the module's own file. An edit anywhere in the package, a retrained model file beside it, changes it."""
    top = module_name.split(".")[0]
    return _source_version(top)


@lru_cache(maxsize=64)
def _source_version(top: str) -> str:
    spec = importlib.util.find_spec(top)
    if spec is None or spec.origin in (None, "built-in", "frozen"):
        files, root = [], None
    elif spec.submodule_search_locations:
        root = Path(next(iter(spec.submodule_search_locations)))
        files = sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    else:
        root = Path(spec.origin).parent
        files = [Path(spec.origin)]
    digest = hashlib.sha256()
    for path in files:
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        size = path.stat().st_size
        digest.update(path.read_bytes() if size <= MAX_HASHED_BYTES else str(size).encode())
        digest.update(b"\0")
    dists = importlib.metadata.packages_distributions().get(top, [])
    version = "0"
    if dists:
        try:
            version = importlib.metadata.version(dists[0])
        except importlib.metadata.PackageNotFoundError:
            pass
    return f"{version}+{digest.hexdigest()[:12]}"


def forget() -> None:
    """Forget every resolved method, its modules and its version, as a new process would (after a method's code
    changed)."""
    tops = {getattr(m.estimate, "__module__", "").split(".")[0] for m in EXTERNAL.values()} - {""}
    for name in [n for n in sys.modules if n.split(".")[0] in tops]:
        del sys.modules[name]
    EXTERNAL.clear()
    _source_version.cache_clear()
    importlib.invalidate_caches()


def versions(names) -> dict[str, str]:
    """``{name: version}`` of the methods from outside the package among ``names`` (resolving them)."""
    out = {}
    for name in names:
        m = resolve(name)
        if m.external:
            out[name] = m.version
    return out
