#!/usr/bin/env bash
# Set up everything mvbb_ros needs on a fresh Debian/Ubuntu machine, idempotently:
#   1. the system library libusb-1.0-0 that Open3D's wheel links against (apt, when root);
#   2. a virtual environment in .venv/ at the repository root (reused when it exists);
#   3. the pinned Python dependencies and the package itself (editable);
#   4. numba's cache of the compiled kernels, warmed (compiled once, then only checked),
#      so that the tests, the demo and the node start warm.
# Called by `make demo` and `make test`; safe to run again at any time.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
python="${PYTHON:-python3}"

have_libusb() { ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; }
if ! have_libusb; then
  if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing libusb-1.0-0 (needed by Open3D) with apt-get"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "bootstrap: Open3D needs the system library libusb-1.0-0, which is missing." >&2
    echo "bootstrap: install it first, e.g.: sudo apt-get install libusb-1.0-0" >&2
    exit 1
  fi
fi

if [ ! -x "$venv/bin/python" ]; then
  echo "bootstrap: creating $venv"
  "$python" -m venv "$venv"
fi

stamp="$venv/.mvbb-installed"
inputs=("$root/requirements.txt" "$root/constraints.txt" "$root/setup.py" "$root/setup.cfg")
if [ ! -f "$stamp" ] || [ -n "$(find "${inputs[@]}" -newer "$stamp" 2>/dev/null)" ]; then
  echo "bootstrap: installing pinned dependencies into $venv (first time: about 2 minutes)"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip==25.3 setuptools==75.8.0 wheel==0.45.1
  "$venv/bin/python" -m pip install -q --disable-pip-version-check \
    -r "$root/requirements.txt" -c "$root/constraints.txt"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e "$root"
  touch "$stamp"
  echo "bootstrap: ready"
fi
# A .venv shared with another checkout (a symlink) may import the package from there, and
# scripts run as files (benchmarks/*.py) would then run that checkout's code: point it here.
installed="$(cd / && "$venv/bin/python" -c 'import mvbb_ros, os; print(os.path.dirname(os.path.dirname(os.path.realpath(mvbb_ros.__file__))))' 2>/dev/null || true)"
if [ "$installed" != "$(realpath "$root")" ]; then
  echo "bootstrap: the package in $venv came from ${installed:-nowhere}; installing $root"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e "$root"
fi
# Every time: a kernel whose source changed since the cache was written compiles here, once.
"$venv/bin/python" -m mvbb_ros.kernels
