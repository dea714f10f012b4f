# The two commands a new user needs (see README): `make demo` and `make test`.
# Both set up .venv/ (and libusb for Open3D) themselves through tools/bootstrap.sh.
# `make check` is the quick loop while editing: the unit tests, without the tests that start ROS
# graphs (marker ros), the slow ones (slow: the kernel cache round trip, colcon builds, the
# demo) and the linters (lint). `make test` is the whole suite but the linters, which
# `make lint` runs once each; CI (.ci/run) runs both.

VENV := .venv
BIN := $(VENV)/bin

# The tests of the compiled kernels (and of the array helpers they share), which `make compat`
# runs on Ubuntu 24.04's numba 0.59, numpy 1.26 and scipy 1.11 (requirements-compat.txt); tests
# needing Open3D or rclpy skip there. The warm-up test calls every kernel of KERNEL_MODULES once,
# also those no listed file runs (the grasp ranking's).
COMPAT_TESTS := test/test_kernels.py::test_every_kernel_module_is_listed_and_warms \
	test/pipeline/test_decode.py test/pipeline/test_filtering.py \
	test/pipeline/test_outliers.py test/pipeline/test_scene_kernels.py \
	test/pipeline/test_density.py \
	test/geometry/views/test_cells.py test/geometry/views/test_objects.py \
	test/geometry/views/test_completion.py test/geometry/boxfit/test_fit.py \
	test/geometry/decomposition/test_split.py test/geometry/grasping/test_surface.py \
	test/test_arrays.py

.PHONY: setup demo check test compat lint bench clean

setup:
	@tools/bootstrap.sh

demo: setup
	$(BIN)/mvbb demo

check: setup
	$(BIN)/python -m pytest -m 'not ros and not slow and not lint'

test: setup
	$(BIN)/python -m pytest -m 'not lint'

compat:
	COMPAT_TESTS="$(COMPAT_TESTS)" tools/compat.sh

# ruff checks what the ROS linters do not (naming, bugbear, pyupgrade, numpy, annotations,
# docstrings present) and formats; ament_flake8 and ament_pep257 (test/test_flake8.py,
# test/test_pep257.py, as `colcon test` runs them) check style, imports, quotes and docstrings.
lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m mypy mvbb_ros
	$(BIN)/python -m pytest -m lint

bench: setup
	$(BIN)/python benchmarks/mvbb.py

clean:
	rm -rf build install log .pytest_cache .ruff_cache .mypy_cache .hypothesis out .venv-compat
