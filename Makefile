# The two commands a new user needs (see README): `make demo` and `make test`.
# Both set up .venv/ (and libusb for Open3D) themselves through tools/bootstrap.sh.

VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup demo test lint bench clean

setup:
	@tools/bootstrap.sh

demo: setup
	$(BIN)/mvbb demo

test: setup
	$(BIN)/python -m pytest

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m mypy mvbb_ros

bench: setup
	$(BIN)/python benchmarks/mvbb.py

clean:
	rm -rf build install log .pytest_cache .ruff_cache .mypy_cache .hypothesis out
