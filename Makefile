# Two commands do all the set-up on a fresh machine (Debian 12, Python 3.11):
#   make demo   - create .venv, install rovlab, run the main job on the default vehicle
#   make test   - create .venv, install rovlab with test extras, lint (ruff), type-check (mypy), run the tests
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out/demo

.PHONY: demo test lint test-slow bench clean clean-cache

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/rovlab demo --out $(OUT)

test: $(STAMP)
	./scripts/ensure-chromium.sh
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

bench: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 $(BIN)/python benchmarks/run_all.py

clean: clean-cache
	rm -rf $(VENV) out build src/*.egg-info

clean-cache:
	rm -rf $${XDG_CACHE_HOME:-$$HOME/.cache}/rovlab/numba
