# Two commands do all the set-up on a fresh machine (Python 3.12 + package registries):
#   make demo   -> the end-to-end demo (creates/reuses the venv, installs, runs)
#   make test   -> the whole test suite (creates/reuses the venv, installs, runs pytest)
# VENV can point outside the clone (CI keys a cached venv on the dependency pins, see .ci/run).
# LeRobot >= 0.5 needs Python 3.12: the first python3.12 that runs (PATH, then pyenv's), or PYTHON=... to choose.
PYTHON ?= $(shell for p in python3.12 $$(pyenv root 2>/dev/null)/versions/3.12*/bin/python3.12 \
	$$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 /usr/bin/python3.12; do \
	$$p -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null && { echo $$p; break; }; done)
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)

.PHONY: install demo test lint
# The dependencies are installed once per pin set (the stamp); the package itself is re-linked every time, so a
# venv shared by several clones (CI's cache) always runs this clone's code.
install: $(STAMP)
	$(BIN)/python -m pip install -q --no-deps -e .

$(STAMP): pyproject.toml
	@test -n "$(PYTHON)" || { echo "Python 3.12 not found: install it (e.g. pyenv install 3.12) or pass PYTHON=/path/to/python3.12"; exit 1; }
	@$(BIN)/python -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null || \
		{ rm -rf $(VENV) && $(PYTHON) -m venv $(VENV); }
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev]"
	$(BIN)/python -m pip check
	@rm -f $(VENV)/.installed-* && touch $@

demo: install
	MUJOCO_GL=egl $(BIN)/skillret-pipeline run --config configs/pipeline/demo.yaml

test: install
	MUJOCO_GL=egl $(BIN)/python -m pytest -q tests

lint: install
	$(BIN)/ruff check . && $(BIN)/ruff format --check . && $(BIN)/lint-imports
