# The two set-up commands of the README: `make demo` and `make test`.
# Each creates .venv (if missing), installs bsjax into it, then runs.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: demo test bench

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

demo: $(PY)
	$(PY) -m pip install -q -e .
	$(VENV)/bin/bsjax demo

# the live view's tests drive a real headless Chromium from the Debian packages (root installs it)
CHROMIUM := command -v chromium-headless-shell >/dev/null || command -v chromium >/dev/null || \
	(apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium-headless-shell)

test: $(PY)
	$(CHROMIUM)
	$(PY) -m pip install -q -e ".[test,haptics,notebooks,cad]"
	$(VENV)/bin/ruff format --check bsjax tests benchmarks
	$(VENV)/bin/ruff check bsjax tests benchmarks
	$(VENV)/bin/pyright
	# a larger main-thread stack: one full run lost a worker to a segfault inside XLA's compiler
	ulimit -s 65536 2>/dev/null; $(PY) -m pytest -q -n 2

bench: $(PY)
	$(PY) -m pip install -q -e ".[bench,haptics]"
	for b in benchmarks/*.py; do $(PY) $$b || exit 1; done
