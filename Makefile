# mrdem — the README's commands. Each target creates .venv on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
export NUMBA_CACHE_DIR ?= $(CURDIR)/.numba-cache
# pytest-xdist processes of `make test`; `mrdem warmup` compiles the kernels once before they start
TEST_WORKERS ?= 2

.PHONY: serve test test-slow test-cluster lint bench venv clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

serve: $(STAMP)    # the service on 127.0.0.1:8000, store under ./data (MRDEM_* to change)
	$(PY) -m service

test: $(STAMP)      # the default run; --durations=15 lists the slowest tests
	$(VENV)/bin/mrdem warmup
	$(PY) -m pytest -q -m "not slow and not cluster" -n $(TEST_WORKERS) --durations=15

CLUSTER_STAMP := $(VENV)/.installed-cluster
$(CLUSTER_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,cluster]'
	touch $(CLUSTER_STAMP)

test-cluster: $(CLUSTER_STAMP)   # a real Ray cluster, PostgreSQL and S3 on this machine (one process)
	$(VENV)/bin/mrdem warmup
	$(PY) -m pytest -q -m cluster -p no:xdist --durations=10

test-slow: $(STAMP)
	$(VENV)/bin/mrdem warmup
	$(PY) -m pytest -q -m "slow and not cluster" -n $(TEST_WORKERS) --durations=15

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports    # the import contracts in pyproject.toml [tool.importlinter]

bench: $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,bench]'
	$(PY) benchmarks/kernels.py

clean:
	rm -rf $(NUMBA_CACHE_DIR) bench-results .pytest_cache .hypothesis
