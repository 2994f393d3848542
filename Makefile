# fohssv: the two commands are `make demo` and `make test`; both set everything up first
# and are quick when the set-up already exists (stamps below).
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
PYTHON ?= python3
VENV := .venv
IN_ENV := scripts/in-env
VENV_STAMP := $(VENV)/.fohssv-requirements
BUILD_STAMP := ros2_ws/install/.fohssv-build
# Package metadata and shipped data: a change here needs a colcon rebuild. Python sources
# do not (the workspace is built with --symlink-install). Not launch/__pycache__: the
# byte-compiling below and every import of the launch file write it, and a rebuild at each
# `make test` followed.
PKG_INPUTS := $(filter-out %/__pycache__,$(wildcard src/*/package.xml src/*/setup.py \
                src/*/setup.cfg src/*/resource/* src/*/config/* src/*/launch/*))
PYTEST_ARGS ?=
# Options of scripts/demo.py for `make demo`, e.g. DEMO_ARGS=--viewer (watch it in Foxglove).
DEMO_ARGS ?=
# Parallel test workers (pytest-xdist; each gets its own ROS domains): a number, auto, or 0 for
# one process. Four on two cores: the graph tests wait on the processes they start, and the
# other workers use those gaps (docs/testing.md).
TEST_WORKERS ?= 4
TEST_PATHS := src/fohssv_sim/test src/fohssv_controller/test tests

.PHONY: setup test demo bench bench-smoke soak lint lock clean help
.DEFAULT_GOAL := help

help:
	@echo "make demo   set up, then run the main job (closed loop over ROS 2, recorded)"
	@echo "make test   set up, then lint and run every test"
	@echo "make bench  set up, then run the benchmarks (figures in bench/RESULTS.md)"
	@echo "make bench-smoke  every benchmark's tiny case (CI runs it after make test)"
	@echo "make soak   the tests under load (busy processes beside each run; CI runs it too)"
	@echo "make setup  only create the venv and build the colcon workspace"

$(VENV_STAMP): requirements.txt constraints.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else "fohssv needs Python >= 3.10, found " + sys.version.split()[0])'
	@test -x $(VENV)/bin/python || { echo "creating $(VENV)"; $(PYTHON) -m venv $(VENV); }
	@echo "installing pinned requirements into $(VENV)"
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check \
	    -r requirements.txt -c constraints.txt
	@touch $(VENV)/COLCON_IGNORE   # colcon would otherwise find dozens of packages in venv/share
	@touch $@

$(BUILD_STAMP): $(VENV_STAMP) $(PKG_INPUTS)
	@echo "building ros2_ws with colcon"
	cd ros2_ws && ../$(IN_ENV) colcon --log-base log build --event-handlers console_cohesion- summary+
	@# the analysis CLI on the venv's PATH: `.venv/bin/fohssv` (or `fohssv` after `source env.sh`)
	@printf '#!/usr/bin/env bash\n# fohssv analysis CLI (written by make setup)\nsource "%s/env.sh" >/dev/null\nexec "%s/ros2_ws/install/fohssv_sim/lib/fohssv_sim/fohssv" "$$@"\n' \
	    "$(CURDIR)" "$(CURDIR)" > $(VENV)/bin/fohssv && chmod +x $(VENV)/bin/fohssv
	@touch $@

setup: $(BUILD_STAMP)

lint: setup
	$(IN_ENV) ruff check src tests bench scripts tools

test: setup
	$(IN_ENV) ruff check src tests bench scripts tools
	@# byte-compile the sources once: hundreds of node and CLI processes start in the tests, and
	@# where PYTHONDONTWRITEBYTECODE is set each would compile every module it imports again
	@$(IN_ENV) python -m compileall -q -j 0 src > /dev/null
	@# and fill numba's on-disk cache once, so the hundreds of processes the tests start compile
	@# nothing (scripts/warm_up.py: which kernels, and why two processes side by side)
	@$(IN_ENV) python scripts/warm_up.py
	@# one BLAS thread per process: the test workers already fill the cores, and OpenBLAS's
	@# threads spin while they wait (a 261 x 261 solve, as in harmonic balance, cost 50 ms of
	@# CPU instead of 1 ms on two busy cores; test_continuation_vehicle 27 CPU s instead of 11)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \
	  $(IN_ENV) python -m pytest -n $(TEST_WORKERS) --dist worksteal -m 'not bench_smoke and not load' $(TEST_PATHS) $(PYTEST_ARGS)

# e.g. make demo DEMO_ARGS=--hosted (the law hosted in the plant: no controller node)
DEMO_ARGS ?=
demo: setup
	$(IN_ENV) python scripts/demo.py $(DEMO_ARGS)

# Every benchmark's tiny case (tests/test_bench.py: scripts/bench.py --quick), so a benchmark
# that no longer starts fails CI (.ci/run runs it after `make test`).
bench-smoke: setup
	$(IN_ENV) python -m pytest -n 2 -m bench_smoke tests/test_bench.py $(PYTEST_ARGS)

# The tests under load (marker load: each starts busy processes that fill every core, so they
# run one at a time, not beside make test's workers): the default closed loop ten times, a
# recorded run and its replay, a recorder's drain at a signal; every bag complete (CI).
soak: setup
	FOHSSV_LAUNCH_RUNS=10 $(IN_ENV) python -m pytest -n 0 -m load $(TEST_PATHS) $(PYTEST_ARGS)

# Every benchmark, its figures and targets into bench/RESULTS.md (committed, overwritten each run).
bench: setup
	$(IN_ENV) python scripts/bench.py --out-dir bench/results --results bench/RESULTS.md

# Regenerate the transitive pins from the current venv.
lock: $(VENV_STAMP)
	{ echo "# Full transitive pins of the venv (pip freeze). Regenerate with 'make lock'."; \
	  $(VENV)/bin/python -m pip freeze --disable-pip-version-check | grep -ivE '^(pip|wheel|setuptools)=='; } > constraints.txt

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log
