#!/usr/bin/env bash
# Run the kernel tests on the oldest supported stack (numba 0.59 / numpy 1.26 / scipy 1.11, as
# on Ubuntu 24.04): `make compat`, and a step of CI.
#   1. .venv-compat/ with exactly requirements-compat.txt (created once, reused while that file
#      is unchanged); no Open3D, rclpy or rosbags, so the tests needing them skip, saying why;
#   2. the package from the work tree (PYTHONPATH, nothing installed), its numba cache in
#      .venv-compat/numba-cache (numba 0.59 must not overwrite the main venv's cache index);
#   3. pytest on the test files of the compiled kernels (COMPAT_TESTS), with the arguments, and
#      hypothesis's examples fixed (a seed): this step looks for what differs between versions;
#      `make test` goes on drawing new examples on the pinned stack.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv-compat"
python="${PYTHON:-python3}"

if [ ! -x "$venv/bin/python" ]; then
  echo "compat: creating $venv"
  "$python" -m venv "$venv"
fi
stamp="$venv/.mvbb-installed"
if [ ! -f "$stamp" ] || [ "$root/requirements-compat.txt" -nt "$stamp" ]; then
  echo "compat: installing requirements-compat.txt into $venv"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$root/requirements-compat.txt"
  touch "$stamp"
fi

cd "$root"
"$venv/bin/python" -c 'import numba, numpy, scipy; print(
    f"compat: numba {numba.__version__}, numpy {numpy.__version__}, scipy {scipy.__version__}")'
export PYTHONPATH="$root${PYTHONPATH:+:$PYTHONPATH}"
export NUMBA_CACHE_DIR="$venv/numba-cache"
# shellcheck disable=SC2086  # COMPAT_TESTS is a list of paths
exec "$venv/bin/python" -m pytest -p no:cacheprovider --hypothesis-seed=0 \
  ${COMPAT_TESTS:?the test files} "$@"
