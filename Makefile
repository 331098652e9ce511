# The two set-up commands: `make dataset` and `make test` (both create .venv when missing).
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: venv dataset test test-slow lint bench clean-venv serve serve-env test-serve browser

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
	$(MAKE) test-serve

# Every bench/bench_*.py with its defaults (those reading a dataset read the one `make dataset`
# builds). bench/probe_*.py analyse a trained run and bench/compare_stage.py two checkouts: they
# take arguments (BENCHMARKS.md gives the commands).
bench: dataset
	for f in bench/bench_*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

clean-venv:
	rm -rf $(VENV)

# The browser testbed (python -m train serve): gradio and playwright live in .venv-serve, in front of
# .venv's packages (torch, OpenCASCADE, the project itself: installed once), so that gradio's
# pillow<13 never reaches the dataset build's pillow 13.0.0 and `make test` needs no gradio.
SERVE_VENV  := .venv-serve
SERVE_PY    := $(SERVE_VENV)/bin/python
SERVE_STAMP := $(SERVE_VENV)/.installed
CHECKPOINT  ?= runs/knife/best.pt
CHROMIUM    ?= /usr/bin/chromium

serve-env: $(SERVE_STAMP)

$(SERVE_STAMP): $(STAMP) requirements-serve.lock
	test -x $(SERVE_PY) || $(PYTHON) -m venv $(SERVE_VENV)
	# pip sees this env alone while it installs; then .venv's site-packages (with their .pth
	# files: the editable project) go after this env's own
	site="$$($(SERVE_PY) -c 'import sysconfig; print(sysconfig.get_path("purelib"))')" && \
	rm -f "$$site/_sketch2patch_main_venv.pth" && \
	$(SERVE_PY) -m pip install -q --disable-pip-version-check --no-deps -r requirements-serve.lock && \
	$(PY) -c "import sysconfig; print('import site; site.addsitedir(%r)' % sysconfig.get_path('purelib'))" \
		> "$$site/_sketch2patch_main_venv.pth"
	$(SERVE_PY) -c "import gradio, playwright, PIL, torch, OCP, train; assert PIL.__version__.startswith('12.')"
	touch $(SERVE_STAMP)

serve: $(SERVE_STAMP)
	$(SERVE_PY) -m train serve --checkpoint $(CHECKPOINT)

# Debian's Chromium for the browser test (Playwright cannot download its own browsers here).
browser:
	@test -x $(CHROMIUM) || { test "$$(id -u)" = 0 || { echo "chromium missing: apt-get install chromium (as root)"; exit 1; }; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium; }

# The slow browser test: a real server, headless Chromium, the STEP read back by OpenCASCADE.
test-serve: $(SERVE_STAMP) browser
	$(SERVE_PY) -m pytest -m slow tests/test_serve_browser.py $(PYTEST_ARGS)
