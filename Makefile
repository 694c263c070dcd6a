# raico: every target installs the project into .venv first if it is missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ARTIFACTS ?= artifacts
JOBS ?= 2

.PHONY: install test test-fast reproduce reproduce-quick bench lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

reproduce: $(STAMP)
	$(BIN)/raico reproduce --all --jobs $(JOBS) --artifacts $(ARTIFACTS)

reproduce-quick: $(STAMP)
	$(BIN)/raico reproduce --all --quick --jobs $(JOBS) --artifacts $(ARTIFACTS)

bench: $(STAMP)
	$(BIN)/python -m bench.run --artifacts $(ARTIFACTS)

lint: $(STAMP)
	$(BIN)/ruff check pipeline plants stages tests bench scripts

clean:
	rm -rf $(VENV) .pytest_cache
