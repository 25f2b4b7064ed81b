# Two entry points for a fresh clone: `make quick` (the main job on built-in defaults) and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup quick test lint bench clean

$(BIN)/vision-rl: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

setup: $(BIN)/vision-rl

quick: setup
	$(BIN)/vision-rl pipeline --quick

test: setup
	$(BIN)/python -m pytest -q

lint: setup
	$(BIN)/ruff check vision_rl tests

bench: setup
	$(BIN)/vision-rl bench sim

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache *.egg-info
