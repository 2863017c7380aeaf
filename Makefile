# The two commands of the README: `make demo` (the main job) and `make test`.
# Each runs the set-up first; it is idempotent and takes about a second when done.
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup demo test lint
setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/bin/aed demo

# Two pytest workers (the machines here have two cores), each test file whole on one worker
# so that its module fixtures are built once.
test: setup
	$(PY) -m pytest -q -p no:cacheprovider -n 2 --dist loadfile

lint: setup
	$(VENV)/bin/ruff check .
