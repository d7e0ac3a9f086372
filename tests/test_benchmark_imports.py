"""The benchmarks and examples run outside the test suite (``make check``, ``make bench``, ``make example``), so a
module moved or a name renamed in the package would first break them there: every ``from harness... import``
they write must resolve."""

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted([*ROOT.glob("benchmarks/*.py"), *ROOT.glob("examples/**/*.py")])


def _harness_imports(path: Path) -> list[tuple[str, str]]:
    return [(node.module, alias.name) for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "harness"
            for alias in node.names]


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_harness_name_a_script_imports_exists(path):
    missing = []
    for module, name in _harness_imports(path):
        mod = importlib.import_module(module)
        if not hasattr(mod, name):
            try:
                importlib.import_module(f"{module}.{name}")
            except ModuleNotFoundError:
                missing.append(f"{module}.{name}")
    assert not missing, missing


def test_the_check_finds_a_stale_import(tmp_path):
    stale = tmp_path / "stale.py"
    stale.write_text("def main():\n    from harness.evaluation.scenario import load_scenario\n")
    module, name = _harness_imports(stale)[0]
    assert not hasattr(importlib.import_module(module), name)
