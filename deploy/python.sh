#!/usr/bin/env bash
# The project's Python environment, and the `selkd` Python package built into it from this
# workspace (maturin + PyO3). Safe to run again: the packages install once; the package is rebuilt
# (incrementally) and reinstalled every time, so the venv always holds this clone's code.
#
#   bash deploy/python.sh              # then: ~/.cache/selkd/python-venv/bin/python
#   SELKD_PYTHON_VENV=DIR bash deploy/python.sh
#
# The venv takes torch from the cache deploy/setup.sh fills (a .pth file, no second 4.6 GB copy),
# and pinned versions of what the package and its tests use: Gymnasium with MuJoCo (the workers'
# `gymnasium:` envs step in it), NumPy, Stable-Baselines3,
# ONNX and onnxruntime, pytest, and maturin to build.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash deploy/setup.sh
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
venv=${SELKD_PYTHON_VENV:-$cache/python-venv}
# Bump `stamp` with any change of the pins below: an older venv is then remade.
stamp=2
pins=(numpy==2.4.6 gymnasium==1.4.0 cloudpickle==3.1.3 pandas==3.1.1 matplotlib==3.11.2
      onnx==1.23.2 onnxruntime==1.31.1 onnxscript==0.7.2 pytest==9.2.0 maturin==1.16.0
      mujoco==4.0.1 imageio==2.38.2)
if [ "$(cat "$venv/.complete" 2>/dev/null)" != "$stamp" ]; then
  echo "python: making $venv (one time, about a minute)" >&2
  rm -rf "$venv"
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check "${pins[@]}"
  # SB3 declares torch as a dependency; torch is already there through the .pth below.
  "$venv/bin/pip" install --quiet --disable-pip-version-check --no-deps stable-baselines3==2.9.2
  site=$("$venv/bin/python" -c 'import site; print(site.getsitepackages()[0])')
  echo "$cache/torch-2.11.0" > "$site/selkd-torch.pth"
  echo "$stamp" > "$venv/.complete"
fi
# Build the extension in the workspace's release profile (it shares target/ with cargo build) and
# install it with the package's Python sources.
log=$(mktemp)
trap 'rm -f "$log"' EXIT
# PYO3_BUILD_EXTENSION_MODULE: an extension does not link libpython (the workspace's binaries,
# which embed Python for `gymnasium:` envs, do); its own target directory keeps the two builds of
# PyO3 from rebuilding each other.
if ! VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH" PYO3_BUILD_EXTENSION_MODULE=1 \
    CARGO_TARGET_DIR="$root/target/python-extension" maturin develop --release \
    --manifest-path python/Cargo.toml > "$log" 2>&1; then
  cat "$log" >&2
  echo "python: building the selkd package failed (above)" >&2
  exit 1
fi
"$venv/bin/python" -c 'import selkd' || { echo "python: the selkd package does not import; see above" >&2; exit 1; }
echo "python: selkd ready in $venv ($venv/bin/python)" >&2
