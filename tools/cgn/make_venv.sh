#!/usr/bin/env bash
# Make .venv-cgn/ at the repository root: the virtual environment that runs Contact-GraspNet
# (cgn-pytorch 0.4.3, its checkpoint inside the wheel) for the physics benchmark, apart from the
# project's .venv, which never gets torch. Idempotent: the environment is reused, and nothing is
# installed again while this script, the requirements, the constraints and the stand-in are unchanged.
#   1. a venv from $PYTHON (default python3, 3.10 or newer);
#   2. pip, setuptools and wheel at the pinned versions;
#   3. torch 2.13.0 (pinned: an open range would pull a multi-GB CUDA build; on this project's
#      machines a CPU build of 2.13.0 lies on disk), torch-geometric 2.7.0 and the rest of
#      tools/cgn/requirements.txt, every version fixed by tools/cgn/constraints.txt;
#   4. cgn-pytorch 0.4.3 without its declared dependencies (they pin torch 2.1.1, numpy 1.26 and
#      torch-cluster, which have no wheels for this Python);
#   5. tools/cgn/torch_cluster_standin: fps, radius and knn in plain torch, importable as
#      torch_cluster (torch_cluster itself has no wheels on PyPI);
#   6. a check that cgn_pytorch imports and its checkpoint loads.
# Usage: tools/cgn/make_venv.sh   (then tools/cgn/server.py runs under .venv-cgn/bin/python)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
venv="$root/.venv-cgn"
python="${PYTHON:-python3}"
pip=("$venv/bin/python" -m pip install --disable-pip-version-check -c "$here/constraints.txt")

say() { echo "make_venv(cgn): $*"; }

inputs_hash() {
  cat "$here/make_venv.sh" "$here/requirements.txt" "$here/constraints.txt" \
    "$here/torch_cluster_standin/pyproject.toml" "$here/torch_cluster_standin/torch_cluster/__init__.py" \
    | sha256sum | cut -d' ' -f1
}

if [ ! -x "$venv/bin/python" ]; then
  say "creating $venv with $("$python" --version 2>&1) ($python)"
  "$python" -m venv "$venv"
else
  say "reusing $venv ($("$venv/bin/python" --version 2>&1))"
fi

stamp="$venv/.mvbb-cgn-installed"
wanted="$(inputs_hash)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$wanted" ]; then
  say "already installed for these inputs (stamp $stamp)"
else
  rm -f "$stamp"
  say "installing pip, setuptools, wheel (pinned)"
  "${pip[@]}" -q pip setuptools wheel
  say "installing the $(grep -cv '^\s*\(#\|$\)' "$here/requirements.txt") requirements of tools/cgn/requirements.txt" \
    "(torch==2.13.0 among them; first time: a few minutes)"
  "${pip[@]}" -q -r "$here/requirements.txt"
  say "installing cgn-pytorch==0.4.3 without its declared dependencies"
  "${pip[@]}" -q --no-deps cgn-pytorch==0.4.3
  say "installing the torch_cluster stand-in from tools/cgn/torch_cluster_standin"
  # from a copy, so that the build leaves no build/ or egg-info in the source tree
  copy="$(mktemp -d)"
  cp -r "$here/torch_cluster_standin/." "$copy"
  "${pip[@]}" -q --no-deps --no-build-isolation --force-reinstall "$copy"
  rm -rf "$copy"
  say "checking that cgn_pytorch imports and its checkpoint loads"
  "$venv/bin/python" - <<'EOF'
import warnings

warnings.simplefilter('ignore')
import contextlib, io, torch, torch_cluster, cgn_pytorch  # noqa: E401
with contextlib.redirect_stdout(io.StringIO()):
    model, _, _ = cgn_pytorch.from_pretrained(device='cpu')
count = sum(p.numel() for p in model.parameters())
print(f'make_venv(cgn): torch {torch.__version__}, cgn_pytorch loaded ({count} parameters), '
      f'torch_cluster from {torch_cluster.__file__}')
EOF
  echo "$wanted" > "$stamp"
fi
say "ready: $venv/bin/python $root/tools/cgn/server.py"
