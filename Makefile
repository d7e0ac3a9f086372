# Front door. `make evaluate` sets up the environment on first use and runs the main job;
# `make test` runs the test suite. Everything runs inside the virtual environment $(VENV).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: setup test evaluate regress rebaseline check bench clean clean-cache

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

# The main job: the default scenario, tables, plots and report under results/default/ (resumes an interrupted
# run; runs of other code or another version of the scenario are set aside: --fresh).
evaluate: $(STAMP)
	$(PY) -m harness evaluate scenarios/default.yaml --jobs 2 --fresh

# CI regression: run scenarios/ci.yaml and compare with results/baseline/ under its tolerances.
regress: $(STAMP)
	$(PY) -m harness regress --scenario scenarios/ci.yaml --baseline results/baseline --fresh

# Deliberately accept the current ci numbers as the new baseline (review the diff before committing it).
rebaseline: $(STAMP)
	$(PY) -m harness rebaseline --scenario scenarios/ci.yaml --baseline results/baseline --fresh

# Acceptance checks that exit non-zero on a miss (scene geometry and rendering, video flows against the surface
# motion, the performer's nearest-class requirement) and the retargeting table over the sample captures in
# ../shared/mocap/cmu. CI runs it.
check: $(STAMP)
	$(PY) benchmarks/scene_acceptance.py
	$(PY) benchmarks/video_flows.py --runs 5
	$(PY) benchmarks/nearest_class.py
	$(PY) benchmarks/retarget_manifest.py

bench: $(STAMP)
	$(PY) benchmarks/kinematics.py
	$(PY) benchmarks/engine_speed.py
	$(PY) benchmarks/pose_evidence.py
	$(PY) benchmarks/dask_throughput.py
	$(PY) benchmarks/video_speed.py

clean: clean-cache
	rm -rf $(VENV) .pytest_cache

# numba's compiled kernels: one directory per version of the kernels' sources (harness.kernel_cache_dir), so
# old versions pile up; this deletes them all, and the caches numba kept next to the sources before that.
clean-cache:
	rm -rf harness/__pycache__/numba
	find harness benchmarks -name '*.nbi' -delete -o -name '*.nbc' -delete
