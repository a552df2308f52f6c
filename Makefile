# The two commands of the README: `make demo` (the whole pipeline on built-in demo data) and `make test`.
VENV ?= .venv
SIZE ?= small
PYTEST_ARGS ?=
# pytest-xdist workers: two on the two-core CI machine (0: one process, e.g. to debug a test)
TEST_WORKERS ?= 2
WORLD ?= ../second-world
WORLD_SEED ?= 0

.PHONY: setup demo test lint bench clean-demo second-world

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/bin/photoshape demo --size $(SIZE)

test: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/pytest -n $(TEST_WORKERS) --durations=15 $(PYTEST_ARGS)

lint: setup
	$(VENV)/bin/ruff check .

bench: setup
	$(VENV)/bin/python bench/render.py
	$(VENV)/bin/python bench/retrieval.py
	$(VENV)/bin/python bench/classifier.py
	$(VENV)/bin/python bench/ingest.py

# The second evaluation world (issue 24): real catalogue shapes and scans rendered by Blender Cycles,
# outside git and outside the test suite; needs `apt-get install -y blender`.
second-world: setup
	$(VENV)/bin/python -m experiments.second_world.build --out $(WORLD) --seed $(WORLD_SEED)
