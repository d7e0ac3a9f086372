# Front door. `make evaluate` sets up the environment on first use and runs the main job;
# `make test` runs the test suite. Everything runs inside the virtual environment $(VENV).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: setup test evaluate bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

evaluate: $(STAMP)
	$(PY) benchmarks/kinematics.py

bench: $(STAMP)
	$(PY) benchmarks/kinematics.py

clean:
	rm -rf $(VENV) .pytest_cache
