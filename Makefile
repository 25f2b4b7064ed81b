# Two entry points for a fresh clone: `make quick` (the main job on built-in defaults) and `make test`.
PYTHON ?= python3
# torch is installed first so that the package's `torch>=2.1` needs nothing more. From PyPI, Linux gets the CUDA build
# (it runs on a CPU too, with gigabytes of CUDA libraries); TORCH_INDEX=https://download.pytorch.org/whl/cpu gets the
# CPU build instead. On a machine with an NVIDIA GPU any CUDA build does: `make setup TORCH_SPEC=torch`.
TORCH_SPEC ?= torch==2.13.0
TORCH_INDEX ?=
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup quick experiment test faults lint bench docs report clean

$(BIN)/vision-rl: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "$(TORCH_SPEC)" $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

setup: $(BIN)/vision-rl

quick: setup
	$(BIN)/vision-rl pipeline --quick

# State SAC over 3 training seeds, the clean recipe at a 25 Hz control step (2M steps each, the cpu preset) with the
# entropy target -4, the learning rate falling to 1e-4 and the weights chosen by 3 held-out starts: mean, spread and
# best of the protocol's lap (docs/results/state-expressway-hatchback-25hz). The three seeds train side by side, one
# process each: a run uses about one core, so on 2 cores three at once finish before two rounds would.
experiment: setup
	$(BIN)/vision-rl experiment --training-seeds 0,1,2 --seeds-at-once 3 --steps 2000000 --control-dt-s 0.04 \
		--steer-action rate_scaled \
		--n-step 8 --guide-label-weight 30 --wall-hit-throttle-cut-s 3.0 --pedal-full-at 0.9 --wall-penalty-c-w 0.002 \
		--target-entropy -4 --learning-rate-final 1e-4 --select-starts 3

# Two test processes: most tests use one core, and those on the shared Ray cluster run in one of them. The suite
# builds the docs site with warnings as errors (tests/test_docs.py), checks that the README's and the docs' result
# tables are what the records give (tests/commands/test_report.py) and builds the wheel (tests/test_wheel.py).
test: setup
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

# The fault-injection suite alone, regenerating its table of outcomes in docs/faults.md.
faults: setup
	$(BIN)/python -m pytest -q tests/faults --fault-table docs/faults.md

lint: setup
	$(BIN)/ruff format --check vision_rl tests
	$(BIN)/ruff check vision_rl tests

bench: setup
	$(BIN)/vision-rl bench sim

# The docs site as `make test` builds it (any warning, a broken link included, is an error), into build/site;
# `$(BIN)/mkdocs serve` shows it while it is edited.
docs: setup
	$(BIN)/mkdocs build --strict --site-dir build/site

# The README's and the docs' result tables, regenerated from the JSON records under docs/results/.
report: setup
	$(BIN)/vision-rl report

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache *.egg-info build dist
