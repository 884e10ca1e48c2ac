.PHONY: setup test test-slow lint format bench results

setup:
	python3 -m venv .venv
	.venv/bin/python -m pip install -c constraints.txt -e ".[dev]"

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
