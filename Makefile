# The two commands of the README: `make demo` (the main job) and `make test` (`make lint` and
# `make docs` for CI).
# Each one sets up ./.venv first (scripts/setup_venv.sh; a no-op when nothing changed).
PY := .venv/bin/python
export PYTHONUNBUFFERED := 1

.PHONY: setup demo test lint docs bench

setup:
	@scripts/setup_venv.sh

demo: setup
	.venv/bin/roadbev demo

test: setup
	$(PY) -m pytest -q tests

# ruff, then mypy (mypy.ini: the whole tree, one strictness). The launch file is checked from its
# folder: run from the root, the folder named launch/ would shadow the ROS `launch` package.
lint: setup
	$(PY) -m ruff check .
	$(PY) -m mypy
	cd launch && $(abspath $(PY)) -m mypy --config-file ../mypy.ini --cache-dir ../.mypy_cache \
		--no-warn-unused-configs roadbev.launch.py

# The Sphinx documentation (docs/, the ROS 2 convention: rosdoc2 builds the same project) into
# docs/_build/html; every warning is an error (-W), all of them reported (--keep-going); read afresh
# every time (-E): the API pages depend on the code, which Sphinx does not watch.
docs: setup
	$(PY) -m sphinx -E -W --keep-going -q -b html docs docs/_build/html

bench: setup
	$(PY) -m benchmarks.run_all
