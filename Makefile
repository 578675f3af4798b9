# softforce: `make demo` and `make test` set everything up on a fresh machine, then run.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.softforce-installed
OUT := out

.PHONY: setup demo test lint bench fuzz clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/install_system_packages.sh
	bash scripts/install_system_packages.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: setup
	bash scripts/demo.sh $(OUT)/demo

# One test file per worker process (its module fixtures are built once), one per core, at
# most four (each holds FE models of a few hundred MB); one BLAS thread each.
test: setup
	OPENBLAS_NUM_THREADS=1 $(BIN)/pytest -q --numprocesses=auto --maxprocesses=4 --dist loadfile

lint: setup
	$(BIN)/ruff check softforce_cli tests scripts benchmarks

bench: setup
	$(BIN)/pytest -q -s -m bench -o addopts="-p no:dash"
	$(BIN)/python benchmarks/run.py --output docs/benchmarks.md

# The fuzz suites with SOFTFORCE_FUZZ_CASES inputs of each kind (default 1000, ~20 min).
fuzz: setup
	SOFTFORCE_FUZZ_CASES=$${SOFTFORCE_FUZZ_CASES:-1000} $(BIN)/pytest -q tests/test_fuzz_harness.py \
		tests/test_fuzz_recordings.py tests/test_fuzz_inputs.py "tests/test_ros2_bag.py::test_damaged_bags_never_crash"

clean:
	rm -rf $(OUT) .pytest_cache .ruff_cache
