# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates the virtual environment in .venv on first use. `make demo` installs the package
# with the [nets] extra (its report compares the default model with the paper's network, which
# trains in PyTorch; no test tools); `make test` adds the test tools and every extra. The plain
# package without PyTorch is `pip install .` (docs/benchmarks.md, "The install").
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check

.PHONY: demo test lint clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.demo-installed: pyproject.toml | $(BIN)/python
	# The CPU wheel of torch lies on this machine; installing it first keeps pip
	# from resolving the multi-GB CUDA build.
	$(PIP) torch==2.13.0
	$(PIP) -e '.[nets]'
	touch $@

$(VENV)/.test-installed: pyproject.toml | $(BIN)/python
	# The CPU wheel of torch lies on this machine; installing it first keeps pip
	# from resolving the multi-GB CUDA build (the [nets] extra, which [test] includes).
	$(PIP) torch==2.13.0
	$(PIP) -e '.[test]'
	# The ROS 2 node's tests need the Jazzy wheels (CPython 3.11, Linux); where they cannot be
	# had the install says so and those tests skip with the reason.
	$(PIP) -e '.[ros2]' || echo "make test: the ROS 2 Jazzy wheels could not be installed; the ROS 2 node tests will skip"
	touch $@ $(VENV)/.demo-installed

# --force: the demo folder holds only what the demo itself made, from its seed.
demo: $(VENV)/.demo-installed
	$(BIN)/skinloc demo --force

# The whole suite (slow tests included) over four pytest-xdist workers on the 2-core machine it
# is measured on: much of a run waits (on a page, a paced live run, a process), and the workers
# beyond two fill those waits (warm tree, quiet, the same hour: 478 s with four against 512 s
# with three; docs/benchmarks.md "The test suite"). tests/conftest.py's worker_scope says which
# tests share a worker, and the units holding a `slow` test start first.
# `make test PYTEST_WORKERS=0` runs it in one process; `pytest -m "not slow"` is the quick
# subset (docs/architecture.md, "Tests").
PYTEST_WORKERS ?= 4

test: $(VENV)/.test-installed
	@sh scripts/ensure-packages.sh chromium firmware
	$(BIN)/ruff check src tests bench
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS)

lint: $(VENV)/.test-installed
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache
