# Set-up and everyday commands. Everything installs into ./.venv from pyproject.toml.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test lint typecheck services bench vendor clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install -e '.[service,train,dev]'
	touch $(STAMP)

install: $(STAMP)

## Simulate a small stereo recording, process it and print the accuracy.
demo: install
	$(BIN)/firefly3d demo

## Lint, type-check and run every test against the machine's real services.
test: install services lint typecheck
	$(BIN)/pytest

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: install
	$(BIN)/mypy pipeline services

## Start PostgreSQL, Redis and RabbitMQ if they are not running (no-op when they are).
services:
	bash scripts/ensure-services.sh

## Benchmarks: scripts that print figures (ratios to baselines measured in the same run).
bench: install services
	$(BIN)/python -m bench.bench_tracking
	$(BIN)/python -m bench.bench_classifier
	$(BIN)/python -m bench.bench_stages
	$(BIN)/python -m bench.bench_simulate
	$(BIN)/python -m bench.bench_service

## Refresh the pages' front-end libraries (package.json) in services/api/static/vendor.
vendor:
	npm ci --no-audit --no-fund
	npm run vendor

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
