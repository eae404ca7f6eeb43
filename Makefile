# The two commands of the README: `make demo` (the main job) and `make test`.
# Each one sets up ./.venv first (scripts/setup_venv.sh; a no-op when nothing changed).
PY := .venv/bin/python
export PYTHONUNBUFFERED := 1

.PHONY: setup demo test lint bench

setup:
	@scripts/setup_venv.sh

demo: setup
	.venv/bin/roadbev demo

test: setup
	$(PY) -m pytest -q tests

lint: setup
	$(PY) -m ruff check .

bench: setup
	$(PY) -m benchmarks.run_all
