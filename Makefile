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
	# XLA's CPU compiler has twice killed a test worker mid-compile (a segfault, then an abort; the
	# test passes when run again): a larger main-thread stack, and a test whose *worker crashed* runs
	# up to twice more (pytest-rerunfailures' xdist crash hook). Ordinary failures are never rerun: the
	# --only-rerun pattern matches no assertion message.
	ulimit -s 65536 2>/dev/null; $(PY) -m pytest -q -n 2 --reruns 2 \
		--only-rerun '^bsjax: rerun only a crashed worker$$'

bench: $(PY)
	$(PY) -m pip install -q -e ".[bench,haptics]"
	for b in benchmarks/*.py; do $(PY) $$b || exit 1; done
