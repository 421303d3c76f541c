# `make demo` and `make test` work on a fresh clone: they create .venv if missing and
# install the project (editable, with its dev extra) before running.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
DEMO_OUT ?= outputs/demo
# make test's parallel workers (pytest-xdist): auto = one per CPU, at most 4; 0 runs in-process.
TEST_WORKERS ?= auto

.PHONY: install demo test test-fast lint clean

install: $(STAMP)

$(STAMP): pyproject.toml setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -e '.[dev]'
	@touch $(STAMP)

# uss-demo: synthetic data, two trainings from the packaged pretrained init (source-only and
# AdaptSegNet), three ONNX exports (+ AdaBN), six SLAM rows of three runs each, table +
# report.md; complete stages are reused (DEMO_ARGS=--force redoes them).
demo: $(STAMP)
	$(VENV)/bin/uss-demo --out $(DEMO_OUT) $(DEMO_ARGS)

# Whole test files go to one worker each (--dist loadfile), so a module's fixtures are built once.
test: $(STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --maxprocesses 4 --dist loadfile

test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow"

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

clean:
	rm -rf outputs .pytest_cache
