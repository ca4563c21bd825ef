# Two commands for a fresh clone:  `make demo`  and  `make test`.
# Both create .venv (Python >= 3.11) and install lobattodae into it on first use, with the
# test and docs extras (the test suite builds the documentation site: tests/test_docs_site.py).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Test processes (pytest-xdist, whole files per process: module fixtures are built once). Two
# fit the 2-core CI machine; each needs up to ~4 GB of memory.
WORKERS ?= 2

.PHONY: demo test test-slow docs docs-serve install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test,docs]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/lobattodae demo --plot convergence.png

test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(WORKERS) --dist loadfile

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow -n $(WORKERS) --dist loadfile

docs: $(STAMP)
	$(BIN)/mkdocs build --strict

docs-serve: $(STAMP)
	$(BIN)/mkdocs serve

clean:
	rm -rf $(VENV) build site *.egg-info src/*.egg-info .pytest_cache
