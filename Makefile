# Two commands: `make demo` and `make test`. Each creates/refreshes .venv and installs everything first.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The CPU build of torch lies on this machine's disk; pinning it keeps pip from fetching a CUDA build.
TORCH := torch==2.13.0

.PHONY: demo test lint format bench model clean venv browser

venv: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q "$(TORCH)"
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/footmesh demo --out demo_out

test: $(STAMP) browser
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	# two test processes on two cores: one BLAS/OpenMP thread each, or they fight over the cores
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -n 2 tests

lint: $(STAMP)
	$(BIN)/ruff check --fix src tests benchmarks
	$(BIN)/ruff format src tests benchmarks

# Debian's chromium for the web app's browser test (skipped with a reason where it cannot be installed)
browser:
	bash scripts/install_browser.sh

bench: $(STAMP)
	$(BIN)/python -m benchmarks

# Rebuild the shape model asset from ../shared/find (reproducible bit for bit).
model: $(STAMP)
	$(BIN)/footmesh model build-from-find --find ../shared/find --out src/footmesh/model/data/foot_model.npz \
		--skin-out src/footmesh/model/data/skin_colours.npz

clean:
	rm -rf $(VENV) demo_out .pytest_cache .ruff_cache
