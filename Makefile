# raico: every target installs the project into .venv first if it is missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
KERNEL := $(VENV)/.kernels
ARTIFACTS ?= artifacts
JOBS ?= 2

.PHONY: install anchors kernels wheel-check test test-fast test-portable test-sanitize reproduce reproduce-quick reproduce-thesis bench lint typecheck docs clean

install: $(STAMP)

# One resolution by pip of everything, the crocoddyl baseline included (the [baseline] extra of
# pyproject.toml) and the documentation site's tools (the [docs] extra), then `pip check`: an inconsistent
# environment stops the install here.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,ray,baseline,docs]'
	$(BIN)/pip check
	touch $(STAMP)

# The crocoddyl baseline is the [baseline] extra, installed by `make install`; `anchors` stays as
# a name for it (older instructions say `make install anchors`).
anchors: install

# The AICO sweep kernel (raico/planning/csweep.c on raico/planning/dense.c, loaded by raico/planning/kernels.py; the plants'
# generated C is built on first use). Built by the one build helper (raico/plants/codegen/c_backend.py)
# with raico/planning/kernels.py's FLAGS for this host's CPU into the kernel cache
# (RAICO_KERNEL_DIR, default ~/.cache/raico/kernels; the flags are part of the file's key, so an
# AVX2/FMA build is never loaded on a CPU without them). A failed build stops make; without gcc
# it says so and the numpy sweeps run.
kernels: $(KERNEL)

$(KERNEL): raico/planning/csweep.c raico/planning/dense.c raico/planning/kernels.py raico/plants/codegen/c_backend.py $(STAMP)
	$(BIN)/python -m raico.planning.kernels
	touch $(KERNEL)

test: $(STAMP) $(KERNEL)
	$(BIN)/python -m pytest -q

test-fast: $(STAMP) $(KERNEL)
	$(BIN)/python -m pytest -q -m "not slow"

# The tests that compare floating-point results (marked `numerics`) under other processors' rounding, on this
# machine (tests/portable.py): numpy's OpenBLAS forced to its Haswell, SkylakeX and Prescott kernels
# (OPENBLAS_CORETYPE), then every compiled kernel built for x86-64-v2 and x86-64-v3 (RAICO_ISA; their own files in
# the kernel cache). Each variant prints its name and the OpenBLAS kernel threadpoolctl reports; any failure fails
# the target. JOBS variants run at once.
test-portable: $(STAMP) $(KERNEL)
	$(BIN)/python -m tests.portable --jobs $(JOBS)

# Every test that reaches compiled code (marked `compiled`) with every kernel, hand-written and generated,
# built with AddressSanitizer and UBSan into its own folder and gcc's sanitizer runtimes preloaded into
# Python (raico/plants/codegen/sanitize.py): an out-of-bounds access or undefined behaviour aborts the run.
SANITIZE_KERNELS ?= $(abspath $(VENV))/.kernels-sanitize

test-sanitize: $(STAMP)
	RAICO_KERNEL_DIR=$(SANITIZE_KERNELS) $(BIN)/python -m raico.plants.codegen.sanitize

reproduce: $(STAMP) $(KERNEL)
	$(BIN)/raico reproduce --all --jobs $(JOBS) --artifacts $(ARTIFACTS)

reproduce-thesis: $(STAMP) $(KERNEL)
	$(BIN)/raico reproduce --all --thesis-setups --jobs $(JOBS) --artifacts $(ARTIFACTS)

reproduce-quick: $(STAMP) $(KERNEL)
	$(BIN)/raico reproduce --all --quick --jobs $(JOBS) --artifacts $(ARTIFACTS)

bench: $(STAMP) $(KERNEL)
	$(BIN)/python -m bench.run --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.learn_any --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.baseline_learn --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.cartpole_pilco --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.payload --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.mpc --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.nao_mpc --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.mpc_learn --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.mpc_learn --experiment experiments/ur5_payload_push_mpc_learn_grav.toml --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.executors --runs 10000 --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.constraint_candidates --artifacts $(ARTIFACTS)
	$(BIN)/python -m bench.truncated_candidate --artifacts $(ARTIFACTS)

lint: $(STAMP) typecheck
	$(BIN)/ruff check raico tests bench scripts

# mypy over the library packages, configured in pyproject.toml ([tool.mypy]: which checks are on and why).
typecheck: $(STAMP)
	$(BIN)/mypy

# The documentation site: docs/ (the reference moved out of the README, the generated results and bench pages,
# the API from the docstrings) built by mkdocs into site/; a warning fails the build (--strict).
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

# A wheel that works: the project built as a wheel (not the editable install) into a fresh virtual environment
# outside the checkout, which then plans a built-in task and a shipped problem file from the package's own data;
# the five floors import only as raico's subpackages there (one install name).
WHEEL_DIR ?= build/wheel-check

wheel-check: $(STAMP)
	rm -rf $(WHEEL_DIR) && mkdir -p $(WHEEL_DIR)
	$(BIN)/pip wheel --quiet --no-deps -w $(WHEEL_DIR) .
	$(PY) -m venv $(WHEEL_DIR)/venv
	$(WHEEL_DIR)/venv/bin/pip install --quiet $(WHEEL_DIR)/raico-*.whl
	cd $(WHEEL_DIR) && venv/bin/python -c "import importlib.util as u; import raico; \
	    assert [n for n in ('pipeline', 'plants', 'planning', 'stages', 'thesis') if u.find_spec(n)] == []"
	cd $(WHEEL_DIR) && venv/bin/raico plan --plant arm5 --task reach --iterations 5 --artifacts art --quiet
	cd $(WHEEL_DIR) && venv/bin/raico plan --problem "$$(venv/bin/python -c 'import raico, pathlib; \
	    print(pathlib.Path(raico.__file__).parent / "problems" / "pendulum_swing-up.toml")')" \
	    --iterations 5 --artifacts art --quiet
	@echo "wheel-check: the wheel installs and plans"

clean:
	rm -rf $(VENV) .pytest_cache site build
