# Two entry points, each bootstraps .venv from pyproject.toml, at the versions of constraints.txt.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MUJOCO_GL ?= egl

.PHONY: demo test wheel-smoke bench venv clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[test,bench]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/ersac-hil demo

# one worker per core, a test file per worker at a time (module fixtures set up once); much of
# the suite waits on processes and Zenoh, so two workers halve it on two cores. Files go out in
# the order pytest collects them (--no-loadscope-reorder; pyproject's testpaths: the long files
# of tests/e2e and tests/protocol first), so the short unit-test files at the end even the
# workers out (xdist's default hands out the files with the most tests first and the one-test
# end-to-end files last); the 25 slowest tests are listed at the end (where the suite's time goes)
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadfile --no-loadscope-reorder --durations=25

# build the wheel, install it into a fresh venv, smoke-test it from outside the tree (CI runs it)
wheel-smoke:
	tools/wheel_smoke.sh $(PYTHON)

bench: $(STAMP)
	$(BIN)/python bench/learner.py --quick
	$(BIN)/python bench/critic.py --quick
	$(BIN)/python bench/sim_speed.py
	$(BIN)/python bench/episode.py
	$(BIN)/python bench/fleet.py
	$(BIN)/python bench/bracing_sweep.py
	$(BIN)/python bench/fault_latency.py
	$(BIN)/python bench/secure_session.py

clean:
	rm -rf $(VENV) build *.egg-info
