# The two commands of the README. Both set everything up first and are safe to re-run.
VENV := .venv
UGVMAP := $(VENV)/bin/ugvmap

.PHONY: setup demo test lint bench

setup:
	@bash scripts/setup.sh

## make demo: local PostGIS, schema, sample data, web map on http://127.0.0.1:8000
## (another port: make demo PORT=8101, or UGVMAP_PORT=8101 in the environment)
PORT ?= $(or $(UGVMAP_PORT),8000)
demo: setup
	$(UGVMAP) db start
	$(UGVMAP) db upgrade
	$(UGVMAP) demo
	$(UGVMAP) serve --host 127.0.0.1 --port $(PORT)

## make test: lint + the whole pytest suite against a throwaway PostGIS database
test: lint
	$(UGVMAP) db start
	$(VENV)/bin/pytest

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy
