# Two commands do all the set-up on a fresh machine (see README):
#   make figures   regenerate every figure into figures/ (the main job)
#   make test      unit tests + every notebook under nbval (fast mode)
# Both create .venv on first use.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.defop-installed
NBVAL  := --nbval-lax --nbval-cell-timeout=600 --nbval-sanitize-with .ci/nbval-sanitize.cfg

.PHONY: figures test setup lint benchmarks clean-venv

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade --quiet pip
	$(BIN)/python -m pip install --quiet -e ".[test,notebook,dask,dev,browser]"
	$(BIN)/python -m defop doctor --browser
	touch $(STAMP)

figures: $(STAMP)
	$(BIN)/python -m defop figures

test: $(STAMP)
	DEFOP_FAST=1 $(BIN)/python -m pytest -p no:cacheprovider tests notebooks $(NBVAL)

lint: $(STAMP)
	$(BIN)/ruff check defop tests benchmarks notebooks

benchmarks: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean-venv:
	rm -rf $(VENV)
