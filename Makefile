# Two user-facing targets: `make demo` (the main job) and `make test`.
# Both set up what they need themselves, idempotently: the system library
# Open3D loads at import (libusb-1.0), a virtual environment and the package.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.vibrissa-installed
OUT ?= out
# The packages' folders (pyproject.toml's package-dir) and the entry point
SRC := vibrissa msgs wire formats mapping planning studies figures streaming runtime launch nodes cli _vibrissa_entry.py

.PHONY: setup demo study test check lint bench clean

setup: $(STAMP)

# pip -qq and PYTHONWARNINGS: only errors, not the index and build-backend notes of every run.
$(STAMP): pyproject.toml
	@echo "setting up $(VENV) (system library, venv, package; a minute or two the first time)"
	bash scripts/ensure_system_deps.sh
	test -x $(PY) || python3 -m venv $(VENV)
	PYTHONWARNINGS=ignore $(PY) -m pip install -qq --upgrade pip
	PYTHONWARNINGS=ignore $(PY) -m pip install -qq -e '.[dev,view]'
	# The package's bytecode, once, as pip compiles a regular install's: an editable install's
	# sources are otherwise compiled at every start where PYTHONDONTWRITEBYTECODE is set
	# (0.2-0.3 s of each command on a 2-core machine; a changed file is recompiled as usual).
	$(PY) -m compileall -q $(SRC)
	# numba's cache of compiled kernels, once (30-75 s on a 2-core VM, idle to loaded; it prints
	# each step), so that a first command is not late by it
	$(PY) scripts/warm_up.py
	touch $(STAMP)

demo: setup
	$(VENV)/bin/vibrissa launch launch/demo.yaml out:=$(OUT)/demo

study: setup
	$(VENV)/bin/vibrissa study paper -o $(OUT)/study

test: setup
	bash scripts/ensure_test_deps.sh
	$(PY) -m ruff check $(SRC) tests benchmarks scripts docs/examples
	$(PY) -m mypy $(SRC) scripts docs/examples
	$(PY) -m pytest -p no:dash -n auto

# The fast loop: lint, types and the tests that start no process and open no socket (the tests
# not marked `live`, see tests/conftest.py) and are not long batteries (`slow`): the core and
# its physics, formats, the codec, node logic.
check: setup
	$(PY) -m ruff check $(SRC) tests benchmarks scripts docs/examples
	$(PY) -m mypy $(SRC) scripts docs/examples
	$(PY) -m pytest -p no:dash -n auto -m "not live and not slow"

bench: setup
	$(PY) benchmarks/bench_mechanics.py
	$(PY) benchmarks/bench_pipeline.py
	$(PY) benchmarks/bench_map.py
	$(PY) benchmarks/bench_next_sweep.py

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info
