# The two set-up commands: `make dataset` and `make test` (both create .venv when missing).
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: venv dataset test test-slow lint bench clean-venv

venv: $(STAMP)

# Re-installs only when the pins change; a no-op (well under a second) otherwise.
$(STAMP): pyproject.toml requirements.lock
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.lock
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

dataset: $(STAMP)
	$(PY) -m workflows.make_dataset

test: $(STAMP)
	$(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

# ruff: a small rule set and the formatter's check (configured in pyproject.toml)
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test-slow: $(STAMP)
	$(PY) -m pytest -m slow $(PYTEST_ARGS)

# Every bench/bench_*.py with its defaults (those reading a dataset read the one `make dataset`
# builds). bench/probe_*.py analyse a trained run and bench/compare_stage.py two checkouts: they
# take arguments (BENCHMARKS.md gives the commands).
bench: dataset
	for f in bench/bench_*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

clean-venv:
	rm -rf $(VENV)
