#!/usr/bin/env bash
# Installs what the build needs and links it into the clone. Safe to run again.
#
# libtorch comes from PyPI's torch==2.11.0 wheel (the version tch 0.24 expects), installed once into a
# per-user cache outside the clone so that every clone on this machine reuses it. `.libtorch` in the
# clone points at it; `.cargo/config.toml` hands that path to tch-sys, and the build bakes it into the
# binaries' rpath, so nothing needs to be set by hand afterwards.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
torch_version=2.11.0
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
target="$cache/torch-$torch_version"

if [ ! -f "$target/.complete" ]; then
  command -v python3 >/dev/null || { echo "setup: python3 with pip is needed to fetch libtorch (apt-get install python3-pip)" >&2; exit 1; }
  echo "setup: installing torch==$torch_version into $target (one time, a few minutes)" >&2
  rm -rf "$target.partial"
  python3 -m pip install --quiet --disable-pip-version-check --no-warn-script-location \
    --target "$target.partial" "torch==$torch_version"
  rm -rf "$target"
  mv "$target.partial" "$target"
  touch "$target/.complete"
fi
ln -sfn "$target/torch" "$root/.libtorch"
[ -f "$root/.libtorch/lib/libtorch_cpu.so" ] || { echo "setup: $root/.libtorch/lib/libtorch_cpu.so is missing; delete $target and run again" >&2; exit 1; }
echo "setup: libtorch ready at $(readlink -f "$root/.libtorch")" >&2
