# One-command entry points. Each target creates the virtual environment it
# needs, so a fresh machine with only Python 3.11 can run them directly.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## demo: fly the paper's Example 1 octahedron (six emulated vehicles over MAVLink)
demo: $(STAMP)
	$(BIN)/gcs-swarm run config/missions/example1_octahedron.yaml

## test: install everything and run the whole test suite (one worker per core)
test: $(STAMP)
	$(BIN)/python -m pytest -n auto --dist worksteal

## lint: ruff (lint + format check) and mypy --strict on the package
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

## bench: run every benchmark (not part of the tests; ~10 min; results in benchmarks/README.md)
bench: $(STAMP)
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python benchmarks/bench_law.py
	$(BIN)/python benchmarks/bench_safety.py
	$(BIN)/python benchmarks/bench_codec.py
	$(BIN)/python benchmarks/bench_station.py --repeat 3
	$(BIN)/python benchmarks/bench_baseline.py
	$(BIN)/python benchmarks/bench_lookahead.py --runs 3
	$(BIN)/python benchmarks/bench_lockstep.py --runs 3
	$(BIN)/python benchmarks/bench_emulator.py
	$(BIN)/python benchmarks/bench_mission_fuzz.py
	$(BIN)/python benchmarks/bench_shards.py --runs 3

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .hypothesis
