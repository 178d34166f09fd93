# pano4d: `make demo` and `make test` set everything up on a fresh machine.
# `make setup` is idempotent: each step leaves a stamp and reruns only when its inputs change.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMPS := $(VENV)/.stamps
RUST_SOURCES := $(shell find crates -type f 2>/dev/null) Cargo.toml Cargo.lock

export VIRTUAL_ENV := $(abspath $(VENV))
export PATH := $(abspath $(VENV))/bin:$(PATH)

.PHONY: setup demo test test-python test-rust lint bench clean

setup: $(STAMPS)/apt $(STAMPS)/python $(STAMPS)/extension $(VENV)/bin/pano4d-view

$(STAMPS)/apt: scripts/install-apt.sh
	scripts/install-apt.sh
	@mkdir -p $(STAMPS) && touch $@

$(STAMPS)/python: pyproject.toml scripts/requirements.py $(STAMPS)/apt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) scripts/requirements.py > $(VENV)/requirements.txt
	$(PY) -m pip install -q -r $(VENV)/requirements.txt
	@mkdir -p $(STAMPS) && touch $@

# The Rust extension pano4d._core, built in release and installed editable into the venv.
$(STAMPS)/extension: $(RUST_SOURCES) $(STAMPS)/python
	$(VENV)/bin/maturin develop --release --quiet
	@touch $@

$(VENV)/bin/pano4d-view: $(RUST_SOURCES)
	cargo build --release --locked -p pano4d-viewer --bin pano4d-view
	install -m 755 target/release/pano4d-view $@

demo: setup
	$(VENV)/bin/pano4d demo demo

test: setup lint test-rust test-python

# Two workers, each test file on one (its module fixtures are built once): on this project's
# 2-core machines the suite took 9 min 21 s instead of 14 min 24 s (bench/RESULTS.md).
PYTEST_WORKERS ?= 2
test-python:
	$(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile

test-rust:
	cargo test --release --locked --workspace

lint:
	$(VENV)/bin/ruff check python tests bench scripts
	cargo fmt --all --check
	cargo clippy --release --locked --workspace --all-targets -- -D warnings
	cargo clippy --release --locked -p splat-core --features python -- -D warnings

bench: setup
	$(PY) bench/synth.py

clean:
	rm -rf $(VENV) target
