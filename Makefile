# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates its own virtual environment in .venv on first use. `make demo` installs the
# plain package (calibrate, localise, the app: no PyTorch, no test tools); `make test` adds
# the test tools and every extra (networks train in PyTorch in the tests).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check

.PHONY: demo test lint clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(BIN)/skinloc: pyproject.toml | $(BIN)/python
	$(PIP) -e .
	touch $@

$(VENV)/.test-installed: pyproject.toml | $(BIN)/python
	# The CPU wheel of torch lies on this machine; installing it first keeps pip
	# from resolving the multi-GB CUDA build (the [nets] extra, which [test] includes).
	$(PIP) torch==2.13.0
	$(PIP) -e '.[test]'
	touch $@ $(BIN)/skinloc

demo: $(BIN)/skinloc
	$(BIN)/skinloc demo

test: $(VENV)/.test-installed
	@sh scripts/ensure-chromium.sh
	$(BIN)/ruff check src tests bench
	$(BIN)/python -m pytest -q

lint: $(VENV)/.test-installed
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache
