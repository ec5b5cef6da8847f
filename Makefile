# make demo | make test | make bench — each installs what it needs (Debian packages, a .venv, the
# package) and reuses what is already there, so a second run only rebuilds what changed.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
BUILD := build/cpp   # make cpp: the C++ library, its tests and benchmarks on their own (no Python)
# make install: the wheel's CMake tree, with the C++ tests (and for make bench the benchmarks), so that make test
# and make bench compile the library once (it was compiled twice, ~6.5 min on 2 cores each time)
DEV := build/dev
APT_PACKAGES := build-essential cmake ninja-build python3-dev python3-venv \
                libeigen3-dev libceres-dev libgtest-dev libbenchmark-dev
PY_BUILD_DEPS := scikit-build-core pybind11 numpy scipy matplotlib pytest
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: demo test bench deps install cpp clean

demo: install
	$(VENV)/bin/fluxcal demo -o build/demo

# pytest: two workers (pytest-xdist) on 2 cores; worksteal, so that the half-minute diagnosis tests left at the
# end do not leave one worker idle. 12.8 min here on 2026-12-07 (the whole .ci/run 17.7 min; stop 88's CI took 30.1
# min before that day's speed-up of the diagnosis, bench/RESULTS.md). Keep .ci/run under 30 min on 2 cores.
test: install
	$(CTEST_BIN) --test-dir $(DEV) --output-on-failure -j 2
	$(PY) -m pytest -q -n 2 --dist worksteal

bench:
	$(MAKE) install BENCH=ON
	for b in ellipsoid twostep refine positions cable kalman planar; do \
	  $(DEV)/bench/bench_$$b --benchmark_min_time=0.5 || exit 1; done
	$(PY) bench/ellipsoid.py
	$(PY) bench/solvers.py
	$(PY) bench/planar.py
	$(PY) bench/positions.py
	$(PY) bench/kalman.py
	$(PY) bench/cable_paper.py build/cable_figs
	$(PY) bench/diagnose.py --real ../shared/data/real --timing
	$(PY) bench/diagnose_cable.py
	$(PY) bench/batch.py
	$(PY) bench/uncertainty.py

# Debian packages: only the missing ones, without recommends (Ceres would pull ~180 MB of GraphBLAS).
deps:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:" $$missing; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(VENV)/.deps: pyproject.toml | deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(PY_BUILD_DEPS)
	touch $@

# The package is built in $(DEV) (a plain `pip install .` uses build/<wheel tag>, pyproject.toml), so
# reinstalling only rebuilds what changed.
# The Debian cmake and ctest (`deps`) named outright: scikit-build-core takes the first `cmake` on PATH and gives it
# 5 s to answer, and a pyenv shim in front of /usr/bin/cmake once timed out ("Could not find CMake with version >=3.18")
# (recursive `=`: looked up when the recipe runs, after `deps` installed them)
CMAKE_BIN = $(firstword $(wildcard /usr/bin/cmake) cmake)
CTEST_BIN = $(firstword $(wildcard /usr/bin/ctest) ctest)
# the Google Benchmark programs: built by make bench (BENCH=ON), not for make test (half a minute of 2 cores)
BENCH ?= OFF
install: $(VENV)/.deps
	CMAKE_EXECUTABLE=$(CMAKE_BIN) \
	$(PY) -m pip install -q --no-build-isolation -C build-dir=$(DEV) \
	  -C cmake.define.FLUXCAL_BUILD_TESTS=ON -C cmake.define.FLUXCAL_BUILD_BENCH=$(BENCH) '.[test]'

cpp: deps
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLUXCAL_BUILD_TESTS=ON -DFLUXCAL_BUILD_BENCH=ON
	cmake --build $(BUILD)

clean:
	rm -rf build $(VENV)
