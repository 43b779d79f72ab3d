# Two commands do all the set-up on a fresh machine (Python 3.11 + package registries):
#   make demo   -> the end-to-end demo (creates/reuses the venv, installs, runs)
#   make test   -> the whole test suite (creates/reuses the venv, installs, runs pytest)
# VENV can point outside the clone (CI keys a cached venv on the dependency pins, see .ci/run).
PYTHON ?= python3.11
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)

.PHONY: install demo test lint
# The dependencies are installed once per pin set (the stamp); the package itself is re-linked every time, so a
# venv shared by several clones (CI's cache) always runs this clone's code.
install: $(STAMP)
	$(BIN)/python -m pip install -q --no-deps -e .

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev]"
	$(BIN)/python -m pip check
	@rm -f $(VENV)/.installed-* && touch $@

demo: install
	MUJOCO_GL=egl $(BIN)/skillret-pipeline run --config configs/pipeline/demo.yaml

test: install
	MUJOCO_GL=egl $(BIN)/python -m pytest -q tests

lint: install
	$(BIN)/ruff check . && $(BIN)/ruff format --check .
