.PHONY: setup test test-slow lint format bench results docs docs-clean

setup:
	python3 -m venv .venv
	.venv/bin/python -m pip install -c constraints.txt -e ".[dev,docs]"

test:
	.venv/bin/python -m pytest

test-slow:
	.venv/bin/python -m pytest -m slow

lint:
	.venv/bin/ruff check .

format:
	.venv/bin/ruff format .

bench:
	.venv/bin/python benchmarks/bench_simulator.py

# The documentation site: every warning is an error; the tutorials run while it builds.
docs:
	.venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html

docs-clean:
	rm -rf docs/_build docs/_generated docs/tutorials docs/sg_execution_times.rst
