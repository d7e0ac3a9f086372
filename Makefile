# Front door. `make evaluate` sets up the environment on first use and runs the main job;
# `make test` runs the test suite. Everything runs inside the virtual environment $(VENV).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: setup test evaluate regress rebaseline example check bench library clean clean-cache

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	@# the distribution was called `harness` before (an unrelated project's name on PyPI): leave one install of it
	$(PY) -m pip uninstall --quiet --yes harness 2>/dev/null || true
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

# The worked example of a method from outside the package (examples/flowclf, docs/methods.md): export runs of
# other seeds and performers, learn the classifier from them, install it, score it beside the engine by both of
# its names (entry point and module:function), and check the two give the same rows. CI runs it.
example: $(STAMP)
	$(PY) -m pip install --quiet -e examples/flowclf
	$(PY) -m harness export examples/flowclf/train.yaml --out results/flowclf_train --jobs 2 --fresh
	$(PY) -m flowclf.train results/flowclf_train --out examples/flowclf/flowclf/model.npz
	$(PY) -m harness evaluate examples/flowclf/compare.yaml --jobs 2 --fresh
	$(PY) examples/flowclf/check.py results/flowclf_compare

# Acceptance checks that exit non-zero on a miss (scene geometry and rendering, video flows against the surface
# motion, the performer's nearest-class requirement), the retargeting table over the sample captures in ../shared/mocap/cmu and ../shared/mocap/bandai,
# and the capture library's own check. CI runs it.
check: $(STAMP)
	$(PY) benchmarks/scene_acceptance.py
	$(PY) benchmarks/video_flows.py --runs 5
	$(PY) benchmarks/nearest_class.py
	$(PY) benchmarks/retarget_manifest.py
	$(PY) -m harness check-library captures

# The capture library (captures/): every row of ../shared/mocap/cmu and ../shared/mocap/bandai retargeted again
# to humanoid56, with each set's terms, and checked (about 4 minutes; commit the result with its reason).
library: $(STAMP)
	$(PY) -m harness build-library ../shared/mocap/cmu ../shared/mocap/bandai --out captures

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
