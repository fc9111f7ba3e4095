# The two set-up commands of the README: `make demo` and `make test`.
# Each creates .venv (if missing), installs bsjax into it, then runs.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: demo test test-min bench

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

demo: $(PY)
	$(PY) -m pip install -q -e ".[all]"
	$(VENV)/bin/bsjax demo

# the live view's tests drive a real headless Chromium from the Debian packages (root installs it)
CHROMIUM := command -v chromium-headless-shell >/dev/null || command -v chromium >/dev/null || \
	(apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium-headless-shell)

test: $(PY)
	$(CHROMIUM)
	$(PY) -m pip install -q -e ".[test,all,notebooks]"
	$(VENV)/bin/ruff format --check bsjax tests benchmarks
	$(VENV)/bin/ruff check bsjax tests benchmarks
	$(VENV)/bin/pyright
	# The 20 slowest tests are printed at the end (the suite's budget is 15 min on 2 cores).
	ulimit -s 65536 2>/dev/null; $(PY) -m pytest -q -n 2 --durations=20

# The declared dependency floors hold: the core at the versions of constraints-min.txt, in its
# own venv, and a smoke subset of the core's tests (no extras: no plot test).
MIN_VENV ?= .venv-min
MIN_PY := $(MIN_VENV)/bin/python
SMOKE := tests/test_errors.py tests/test_boundary.py tests/test_bad_input.py \
	tests/test_batch.py::test_map_equals_vmap_and_a_loop \
	tests/test_batch.py::test_map_accepts_lists_and_works_inside_jit_and_grad \
	tests/test_merge_refit.py::test_closest_points_plane_and_clamped_edges \
	tests/test_merge_refit.py::test_closest_points_periodic_crosses_the_seam \
	tests/test_merge_refit.py::test_projection_bad_input_eager_and_jit \
	tests/test_optimise.py::test_least_squares_matches_scipy \
	--deselect tests/test_bad_input.py::test_plot_bad_input_names_the_argument

$(MIN_PY):
	$(PYTHON) -m venv $(MIN_VENV)
	$(MIN_PY) -m pip install -q --upgrade pip

test-min: $(MIN_PY)
	$(MIN_PY) -m pip install -q -c constraints-min.txt -e ".[test]"
	BSJAX_CACHE_DIR=.cache/jax-min $(MIN_PY) -m pytest -q -p no:cacheprovider $(SMOKE)

bench: $(PY)
	$(PY) -m pip install -q -e ".[bench,all]"
	for b in benchmarks/*.py; do $(PY) $$b || exit 1; done
