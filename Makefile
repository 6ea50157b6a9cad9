# Two commands do all of the set-up on a fresh machine: `make run` and `make test`.
# Both are idempotent: the install step runs again only when pyproject.toml changes.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCH := torch==2.13.0

.PHONY: run test test-fast lint install system-deps bytecode clean

run: install
	$(BIN)/walkcap tui

test: install lint
	$(BIN)/python -m pytest -q

# The suite without its slow and cluster tests (markers in pyproject.toml), for each step.
test-fast: install lint
	$(BIN)/python -m pytest -q -m "not slow and not cluster"

# Style and the one-way imports (devices -> inference -> capture -> tui), as CI runs them.
lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

install: system-deps $(STAMP) bytecode

# Compiled once here: where PYTHONDONTWRITEBYTECODE is set, every process would otherwise
# compile walkcap's sources again at start, and replay's reader process would start
# 40-80 ms later. Up-to-date files are skipped. The numba kernels too (inference.compiled):
# 15-20 s the first time, then a cached check.
bytecode: $(STAMP)
	@$(BIN)/python -m compileall -q capture devices inference tui >/dev/null
	@$(BIN)/python -m inference.compiled

# Open3D loads libusb-1.0 at import time; a fresh Debian machine lacks it.
system-deps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "Installing libusb-1.0-0 (needed by Open3D)"; \
	    (apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 || \
	     (apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null)) || exit 1; \
	  else \
	    echo "Open3D needs libusb-1.0. Run: sudo apt-get install -y libusb-1.0-0" >&2; exit 1; \
	  fi; \
	fi

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@# torch first, pinned: a local CPU wheel. Unpinned, it drags in GBs of CUDA packages.
	$(BIN)/python -c "import torch" 2>/dev/null || $(BIN)/pip install -q $(TORCH)
	$(BIN)/pip install -q -e ".[dev,cluster]"
	@touch $(STAMP)

clean:
	rm -rf $(VENV) *.egg-info
