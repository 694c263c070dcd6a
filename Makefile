# raico: every target installs the project into .venv first if it is missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ANCHORS := $(VENV)/.anchors
KERNEL := build/csweep.so
ARTIFACTS ?= artifacts
JOBS ?= 2

.PHONY: install anchors kernels test test-fast reproduce reproduce-quick bench lint clean

install: $(STAMP)

$(STAMP): pyproject.toml | $(KERNEL)
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,ray]'
	touch $(STAMP)

# The AICO sweep kernel (stages/plan/csweep.c, loaded by stages/plan/kernels.py; the plants' generated
# C is built on first use into ~/.cache/raico/kernels). Without gcc the numpy sweeps run.
kernels: $(KERNEL)

# The flags are stages/plan/kernels.py's FLAGS (that list builds the kernel when this target has not
# run); they are spelled out here because this target runs before the venv exists.
$(KERNEL): stages/plan/csweep.c
	@mkdir -p build
	gcc -O3 -fPIC -shared -fno-fast-math -ffp-contract=fast -fopenmp-simd -fno-strict-aliasing \
		$$(grep -q ' avx2' /proc/cpuinfo && grep -q ' fma' /proc/cpuinfo && echo -mavx2 -mfma) -o $@ $< -lm \
		|| echo "kernels: no C compiler, the numpy sweeps run"

# The crocoddyl baseline: the pinned list [tool.raico] anchors of pyproject.toml (why not an extra:
# see there), without dependency resolution; about 15 s from an empty pip cache.
anchors: $(ANCHORS)

$(ANCHORS): $(STAMP) pyproject.toml
	$(BIN)/pip install --quiet --no-deps $$($(BIN)/python -c 'import tomllib; print(" ".join(tomllib.load(open("pyproject.toml", "rb"))["tool"]["raico"]["anchors"]))')
	$(BIN)/python -c "import crocoddyl, pinocchio"
	touch $(ANCHORS)

test: $(STAMP) $(ANCHORS)
	$(BIN)/python -m pytest -q

test-fast: $(STAMP) $(ANCHORS)
	$(BIN)/python -m pytest -q -m "not slow"

reproduce: $(STAMP) $(ANCHORS)
	$(BIN)/raico reproduce --all --jobs $(JOBS) --artifacts $(ARTIFACTS)

reproduce-quick: $(STAMP) $(ANCHORS)
	$(BIN)/raico reproduce --all --quick --jobs $(JOBS) --artifacts $(ARTIFACTS)

bench: $(STAMP) $(ANCHORS)
	$(BIN)/python -m bench.run --artifacts $(ARTIFACTS)

lint: $(STAMP)
	$(BIN)/ruff check pipeline plants stages tests bench scripts

clean:
	rm -rf $(VENV) .pytest_cache
