# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates its own virtual environment in .venv on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test lint clean

$(BIN)/skinloc: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	# The CPU wheel of torch lies on this machine; installing it first keeps pip
	# from resolving the multi-GB CUDA build.
	$(BIN)/python -m pip install --quiet --disable-pip-version-check torch==2.13.0
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test]'
	touch $@

demo: $(BIN)/skinloc
	$(BIN)/skinloc demo

test: $(BIN)/skinloc
	@sh scripts/ensure-chromium.sh
	$(BIN)/ruff check src tests bench
	$(BIN)/python -m pytest -q

lint: $(BIN)/skinloc
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache
