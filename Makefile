# The two commands a new user needs (see README): `make demo` and `make test`.
# Both set up .venv/ (and libusb for Open3D) themselves through tools/bootstrap.sh.

VENV := .venv
BIN := $(VENV)/bin

# The tests of the compiled kernels (and of the array helpers they share), which `make compat`
# runs on Ubuntu 24.04's numba 0.59, numpy 1.26 and scipy 1.11 (requirements-compat.txt); tests
# needing Open3D or rclpy skip there.
COMPAT_TESTS := test/test_decode.py test/test_filtering.py test/test_outliers.py \
	test/test_objects.py test/test_completion.py test/test_fit.py test/test_split.py \
	test/test_surface.py test/test_arrays.py

.PHONY: setup demo test compat lint bench clean

setup:
	@tools/bootstrap.sh

demo: setup
	$(BIN)/mvbb demo

test: setup
	$(BIN)/python -m pytest

compat:
	COMPAT_TESTS="$(COMPAT_TESTS)" tools/compat.sh

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m mypy mvbb_ros

bench: setup
	$(BIN)/python benchmarks/mvbb.py

clean:
	rm -rf build install log .pytest_cache .ruff_cache .mypy_cache .hypothesis out .venv-compat
