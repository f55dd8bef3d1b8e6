# Two entry points on a fresh machine: `make bench` (the main job) and `make test`.
# Both bootstrap .venv and a libLLVM >= 16 first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.mitsnerf-installed

.PHONY: setup bench lint test test-slow check clean

setup: $(STAMP)

# The ray extra: the test suite runs a tiny sweep on a local Ray instance (about 100 MB download, 350 MB installed).
$(STAMP): pyproject.toml scripts/ensure_llvm.sh Makefile
	PYTHON=$(PYTHON) bash scripts/ensure_llvm.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -e '.[test,ray]'
	touch $(STAMP)

# mitsnerf bench ends with where its datasets are and the next commands, spelled $(VENV)/bin/mitsnerf here.
bench: setup
	$(VENV)/bin/mitsnerf bench $(ARGS)
	@echo "(the mitsnerf command is in $(VENV)/bin: '. $(VENV)/bin/activate' puts it on PATH in this shell)"

# ruff on the package, its examples and benchmarks, mypy on the package (pyproject.toml configures both), then the tests.
lint: setup
	$(PY) -m ruff check mitsnerf examples benchmarks
	$(PY) -m mypy

test: lint
	$(PY) -m pytest -q -m "not slow" $(ARGS)

test-slow: setup
	$(PY) -m pytest -q -m slow $(ARGS)

check: setup
	$(VENV)/bin/mitsnerf check $(ARGS)

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
