"""The distribution: its own name (not the unrelated `harness` on PyPI), a licence, and every file the package
reads shipped in a wheel (`pip install .` outside a checkout)."""

import fnmatch
import tomllib
from pathlib import Path

import harness
from harness.body import model as body_model

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_the_distribution_has_its_own_name_and_a_licence():
    project = PYPROJECT["project"]
    assert project["name"] == "monocular-motion-harness"
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    readme = (ROOT / "README.md").read_text()
    assert readme.splitlines()[0].startswith("# monocular-motion-harness:")
    assert "MIT licence" in readme and "own terms" in readme


def test_every_data_file_of_the_package_is_package_data():
    """A file of the package that is not Python (a table the code reads) reaches a wheel only through
    package-data: each must match one of its patterns."""
    patterns = PYPROJECT["tool"]["setuptools"]["package-data"]["harness"]
    package = Path(harness.__file__).resolve().parent
    data = [p.relative_to(package).as_posix() for p in package.rglob("*")
            if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts]
    assert data, "the package's tables (the performer's calibration, the human floor) should be found"
    missing = [d for d in data if not any(fnmatch.fnmatch(d, pat) or fnmatch.fnmatch(d, pat.replace("**/", ""))
                                          for pat in patterns)]
    assert not missing


def test_an_install_outside_a_checkout_finds_the_body_model_where_the_wheel_puts_it():
    files = PYPROJECT["tool"]["setuptools"]["data-files"]
    (target, sources), = files.items()
    assert sources == ["models/humanoid56.xml"]
    assert body_model._INSTALLED_MODEL.as_posix().endswith(f"{target}/humanoid56.xml")
    assert body_model.DEFAULT_MODEL_PATH == body_model._CHECKOUT_MODEL     # in a checkout, the checkout's
