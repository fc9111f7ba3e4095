# The two set-up commands of the README: `make demo` and `make test`.
# Each creates .venv (if missing), installs bsjax into it, then runs.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: demo test test-min bench docs

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

demo: $(PY)
	$(PY) -m pip install -q -e ".[all]"
	$(VENV)/bin/bsjax demo

# the live view's tests drive a real headless Chromium from the Debian packages (root installs it)
CHROMIUM := command -v chromium-headless-shell >/dev/null || command -v chromium >/dev/null || \
	(apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium-headless-shell)

# the docs build of `make test`, which tests/test_docs.py then checks instead of building again
TEST_SITE := $(CURDIR)/build/test-site
test: export BSJAX_DOCS_SITE := $(TEST_SITE)
test: $(PY)
	$(CHROMIUM)
	$(PY) -m pip install -q -e ".[test,all,notebooks,docs]"
	$(VENV)/bin/ruff format --check bsjax tests benchmarks
	$(VENV)/bin/ruff check bsjax tests benchmarks
	$(VENV)/bin/pyright
	$(MAKE) docs-build SITE=$(TEST_SITE)
	# The 20 slowest tests are printed at the end (the suite's budget is 15 min on 2 cores).
	ulimit -s 65536 2>/dev/null; $(PY) -m pytest -q -n 2 --durations=20
	# the declared floors, once per run (~40 s: a second venv at constraints-min.txt, a smoke subset)
	$(MAKE) test-min

# The declared dependency floors hold: the core at the versions of constraints-min.txt, in its
# own venv, and a smoke subset of the core's tests (no extras: no plot test). `make test` ends
# with it, so CI checks the floors on every run.
MIN_VENV ?= .venv-min
MIN_PY := $(MIN_VENV)/bin/python
SMOKE := tests/test_errors.py tests/test_boundary.py \
	tests/test_batch.py::test_map_equals_vmap_and_a_loop \
	tests/test_batch.py::test_map_accepts_lists_and_works_inside_jit_and_grad \
	tests/test_merge_refit.py::test_closest_points_plane_and_clamped_edges \
	tests/test_merge_refit.py::test_closest_points_periodic_crosses_the_seam \
	tests/test_merge_refit.py::test_projection_bad_input_eager_and_jit \
	tests/test_optimise.py::test_least_squares_matches_scipy

$(MIN_PY):
	$(PYTHON) -m venv $(MIN_VENV)
	$(MIN_PY) -m pip install -q --upgrade pip

test-min: $(MIN_PY)
	$(MIN_PY) -m pip install -q -c constraints-min.txt -e ".[test]"
	BSJAX_CACHE_DIR=.cache/jax-min $(MIN_PY) -m pytest -q -p no:cacheprovider $(SMOKE)

# The documentation site (mkdocs.yml, docs/): built with --strict, so a broken link, anchor or
# API reference fails; `make test` runs the build (into a temporary directory).
SITE ?= build/site
docs: $(PY)
	$(PY) -m pip install -q -e ".[docs]"
	$(MAKE) docs-build SITE=$(SITE)

docs-build:
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet -d $(SITE)

bench: $(PY)
	$(PY) -m pip install -q -e ".[bench,all]"
	for b in benchmarks/*.py; do $(PY) $$b || exit 1; done
